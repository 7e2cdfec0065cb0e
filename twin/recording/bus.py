"""How other hooks find the session's recording: ``recording_for(session)`` (None when not recording).

Hooks are created independently from the CLI options and do not know each other; the recording hook
registers itself here for its session, and e.g. the UDM hook adds its answers to that recording.
"""

from __future__ import annotations

import weakref
from typing import Any

_by_session: weakref.WeakKeyDictionary[Any, Any] = weakref.WeakKeyDictionary()
_by_id: dict[int, Any] = {}  # for session objects that cannot be weakly referenced


def attach(session: Any, recording: Any) -> None:
    try:
        _by_session[session] = recording
    except TypeError:
        _by_id[id(session)] = recording


def detach(session: Any) -> None:
    try:
        _by_session.pop(session, None)
    except TypeError:
        _by_id.pop(id(session), None)


def recording_for(session: Any) -> Any | None:
    try:
        return _by_session.get(session)
    except TypeError:
        return _by_id.get(id(session))
