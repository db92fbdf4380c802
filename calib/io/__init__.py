"""What calib reads and writes: the CSV contract (and its compiled scanner), calibration files, atomic writes,
digests."""
