"""The converter of official Lightning checkpoints to raypatch model files."""
