"""Making a plan, before anything runs: what planning knows of a station and its DUTs (stated, commissioned,
or measured from an earlier session), how long a point, a sweep and a wait take, and `rig design`'s least-time
plan. The schedules (rig/schedules/) compile and time plans with it."""
