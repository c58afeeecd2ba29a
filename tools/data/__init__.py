"""Golden cases, procedural scenes, training and the small random-weight models the tests share."""
