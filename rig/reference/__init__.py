"""The reference chain as a run uses it: the site field and the reference magnetometer, the run's ambient,
what a session records of the chain, and its part of `rig check`. The chain is established by `rig commission`
(rig/commission/) and sealed in the commissioning file (rig/config/commissioning_file.py)."""
