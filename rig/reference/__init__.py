"""The reference chain: the commissioning procedure and its sealed file, the site field and the reference
magnetometer, what a session records of the chain, its part of `rig check`, the run's ambient, and the
uncertainty budget's inputs; loading a plan with its station's commissioning (loading.py)."""
