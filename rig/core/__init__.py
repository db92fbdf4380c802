"""What every layer of rig/ shares: the error family, the names and numbers rules, YAML loading with located
errors, the paths a run writes, the config base types and the points a plan compiles to."""
