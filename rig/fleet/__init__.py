"""The fleet database: sessions of every rig copied into PostgreSQL, listed across rigs, and re-fitted in
batch on a Dask cluster. SQLite session files stay the rigs' own record; this is a copy for the line.

    source.py   session_snapshot(path): the one reader of session files (every table, read-only)
    schema.py   connect(url), the fleet tables, and the per-table copies made on demand
    push.py     push(conn, snapshot): one transaction per session, content-hashed, COPY for rows
    query.py    list_sessions(...) with filters; the rows of one session for a re-fit
    batch.py    refit-all on Dask: one results row per DUT, failures included, Parquet and the database
"""

from rig.core.errors import MagrigError

DATE_FORMATS = ("%Y-%m-%d", "%Y-%m-%dT%H:%M", "%Y-%m-%dT%H:%M:%S")  # the listing's --since / --until (UTC)


class FleetError(MagrigError):
    """The fleet database cannot be reached, or refuses what was sent."""
