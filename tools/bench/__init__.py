"""PyTorch timing for raypatch-bench, evaluation, baselines, figures and the GPU-machine kit."""
