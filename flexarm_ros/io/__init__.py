"""File input/output: tables (CSV, NPZ); MCAP comes with the ROS twin."""
