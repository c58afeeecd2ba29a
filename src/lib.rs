pub use raypatch_engine; pub use raypatch_model;
