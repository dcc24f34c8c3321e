"""The central learner and the driver of the DAgger rounds (serial or on Ray)."""
