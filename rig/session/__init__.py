"""The session file (SQLite): its schema and migrations, the writer the run uses, the rows it stores, the
read-only reader every other command uses, the run lock, the request inbox and the temperature log."""
