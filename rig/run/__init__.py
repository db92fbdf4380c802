"""A campaign run: the runner (tasks and the handlers of their commands), the run itself (session, lock, rig,
engine, post-run fits) and the terminal's live display."""
