"""`notify:` of a plan or a station: where the run sends word to the operator (rig/run/notify.py).

    notify: [mailto://lab-smtp.example.org?to=oncall@example.org, ntfy://ntfy.sh/magrig-bench-2]
    notify:
      urls: [json://127.0.0.1:8080/magrig]  # Apprise URLs: mailto://, matrix://, slack://, ntfy://, json://
      stalled_after_min: 30    # no point recorded for this long (the run's clock): say so
      repeat_after_min: 10     # at most one message of each kind (hold, pause...) per this long

A plain list is `urls:` with the defaults. The plan's `notify:` replaces the station's whole (the station
names who looks after the bench, a plan may send its campaign's word elsewhere). Each URL is checked by
Apprise when the file is read, so a mistyped one is refused naming the file, key and line; apprise is
imported only then.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import AfterValidator, Field, model_validator

from rig.core.configbase import Strict
from rig.core.numbers import bounded

MAX_URLS = 20
MAX_URL_CHARS = 2000


def _check_url(url: str) -> str:
    problem = url_problem(url)
    if problem:
        raise ValueError(problem)
    return url


AppriseUrl = Annotated[str, AfterValidator(_check_url)]


class Notify(Strict):
    urls: list[AppriseUrl] = Field(min_length=1, max_length=MAX_URLS, description="Apprise URLs")
    stalled_after_min: bounded(gt=0, hi=7 * 24 * 60) | None = Field(
        30.0, description="no point recorded for this many minutes of the run's clock: a message "
        "(null: never)")
    repeat_after_min: bounded(lo=0, hi=24 * 60) = Field(
        10.0, description="at most one message of each kind per this many minutes; the next one counts "
        "those held back")

    @model_validator(mode="before")
    @classmethod
    def _plain_list(cls, data: Any) -> Any:
        return {"urls": data} if isinstance(data, list) else data


def url_problem(url: str) -> str | None:
    """What is wrong with an Apprise URL (None: Apprise takes it). The URL is never repeated whole: it
    may carry a password or a token."""
    if not url or len(url) > MAX_URL_CHARS or "://" not in url:
        return "not an Apprise URL (scheme://..., e.g. mailto://host?to=someone@example.org)"
    import apprise  # only for a plan or station that has notify:

    scheme = url.split("://", 1)[0]
    if not apprise.Apprise().add(url):
        return (f"Apprise does not take this {scheme}:// URL (unknown scheme, or a part missing or "
                "malformed; see the Apprise wiki for its form)")
    return None
