"""The run engine: the command vocabulary tasks yield (commands.py), the executor that alone pauses, holds,
retakes and ends safe (executor.py), and the judges of temperature stability (stability.py, frozen.py)."""
