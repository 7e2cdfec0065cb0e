"""Where UDM objects live: the ``Store`` interface and its default, SQLite with an R*Tree spatial index.

The server only talks to ``Store``; a PostGIS store for city-scale data (``ST_DWithin`` on a geography
column) can replace ``SqliteRtreeStore`` without touching the HTTP layer.

Why R*Tree and a second, exact filter: the R*Tree module stores 32-bit floats and rounds boxes outwards, so
it is a fast, conservative prefilter (about 1 m slack at city latitudes). The exact answer comes from
comparing the 64-bit ``lat``/``lon`` columns (for boxes) or the haversine distance (for radius queries).
"""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

from twin.udm.model import BBox, Extent, UdmObject, boxes_around, haversine_m

DEFAULT_LIMIT = 1000
IN_MEMORY = ":memory:"


@runtime_checkable
class Store(Protocol):
    """What the HTTP layer needs from a spatial object store; ``now`` is POSIX seconds (default: clock)."""

    def upsert(self, objects: Iterable[UdmObject], now: float | None = None) -> list[UdmObject]:
        """Insert or replace objects by id; returns them with ``created_at``/``updated_at`` filled in."""
        ...

    def delete(self, object_id: str) -> bool:
        """Remove one object; False when there was none with that id."""
        ...

    def get(self, object_id: str, now: float | None = None) -> UdmObject | None:
        """One object by id, or None when it does not exist or has expired."""
        ...

    def in_bbox(
        self, bbox: BBox, *, layers: Sequence[int] | None = None, types: Sequence[str] | None = None,
        now: float | None = None, limit: int = DEFAULT_LIMIT,
    ) -> list[UdmObject]:
        """Unexpired objects whose position lies in the box (edges included), at most ``limit``."""
        ...

    def within_radius(
        self, lat: float, lon: float, radius_m: float, *, layers: Sequence[int] | None = None,
        types: Sequence[str] | None = None, now: float | None = None, limit: int = DEFAULT_LIMIT,
    ) -> list[UdmObject]:
        """Unexpired objects within ``radius_m`` great-circle metres, nearest first, at most ``limit``."""
        ...

    def purge_expired(self, now: float | None = None) -> int:
        """Delete every object whose ``valid_until`` has passed; returns how many went."""
        ...

    def count(self) -> int:
        """How many objects are stored, expired ones not yet purged included."""
        ...

    def close(self) -> None: ...


_SCHEMA = """
CREATE TABLE IF NOT EXISTS objects (
    row_key     INTEGER PRIMARY KEY,      -- the R*Tree's integer id; object ids are text
    object_id   TEXT NOT NULL UNIQUE,
    layer       INTEGER NOT NULL,
    type        TEXT NOT NULL,
    class       TEXT NOT NULL DEFAULT '',
    name        TEXT NOT NULL DEFAULT '',
    lat         REAL NOT NULL,
    lon         REAL NOT NULL,
    alt         REAL,
    heading     REAL,
    length      REAL,
    width       REAL,
    height      REAL,
    created_at  REAL NOT NULL,
    updated_at  REAL NOT NULL,
    valid_until REAL,
    source      TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS objects_valid_until ON objects (valid_until) WHERE valid_until IS NOT NULL;
CREATE VIRTUAL TABLE IF NOT EXISTS objects_rtree USING rtree (row_key, min_lon, max_lon, min_lat, max_lat);

-- Triggers keep the index in step with the table, so no code path can forget it.
CREATE TRIGGER IF NOT EXISTS objects_rtree_insert AFTER INSERT ON objects BEGIN
    INSERT INTO objects_rtree VALUES (new.row_key, new.lon, new.lon, new.lat, new.lat);
END;
CREATE TRIGGER IF NOT EXISTS objects_rtree_move AFTER UPDATE OF lat, lon ON objects BEGIN
    UPDATE objects_rtree SET min_lon = new.lon, max_lon = new.lon, min_lat = new.lat, max_lat = new.lat
    WHERE row_key = new.row_key;
END;
CREATE TRIGGER IF NOT EXISTS objects_rtree_delete AFTER DELETE ON objects BEGIN
    DELETE FROM objects_rtree WHERE row_key = old.row_key;
END;
"""

_COLUMNS = (
    "object_id, layer, type, class, name, lat, lon, alt, heading, length, width, height, "
    "created_at, updated_at, valid_until, source"
)

_UPSERT = f"""
INSERT INTO objects ({_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)
ON CONFLICT (object_id) DO UPDATE SET
    layer = excluded.layer, type = excluded.type, class = excluded.class, name = excluded.name,
    lat = excluded.lat, lon = excluded.lon, alt = excluded.alt, heading = excluded.heading,
    length = excluded.length, width = excluded.width, height = excluded.height,
    updated_at = excluded.updated_at, valid_until = excluded.valid_until, source = excluded.source
RETURNING created_at
"""


class SqliteRtreeStore:
    """The default store: one SQLite file (or memory) with an R*Tree over object positions.

    One connection guarded by a lock: SQLite serialises writers anyway, and every query here takes well
    under a millisecond, so a pool would add contention without adding throughput.
    """

    def __init__(self, path: str | Path = IN_MEMORY) -> None:
        self.path = str(path)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        if self.path != IN_MEMORY:
            # WAL lets a second process read (e.g. sqlite3 on the command line) while the server writes.
            self._db.execute("PRAGMA journal_mode = WAL")
            self._db.execute("PRAGMA synchronous = NORMAL")
        self._db.executescript(_SCHEMA)

    def upsert(self, objects: Iterable[UdmObject], now: float | None = None) -> list[UdmObject]:
        now = time.time() if now is None else now
        stored = []
        with self._lock:
            self._db.execute("BEGIN")
            try:
                for obj in objects:
                    extent = obj.extent or Extent()
                    row = (
                        obj.id, obj.layer, obj.type, obj.object_class, obj.name, obj.lat, obj.lon, obj.alt,
                        obj.heading, extent.length, extent.width, extent.height, now, now, obj.valid_until,
                        obj.source,
                    )
                    (created_at,) = self._db.execute(_UPSERT, row).fetchone()
                    stored.append(obj.with_times(created_at, now))
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
        return stored

    def delete(self, object_id: str) -> bool:
        with self._lock:
            return self._db.execute("DELETE FROM objects WHERE object_id = ?", (object_id,)).rowcount > 0

    def get(self, object_id: str, now: float | None = None) -> UdmObject | None:
        now = time.time() if now is None else now
        sql = (f"SELECT {_COLUMNS} FROM objects "
               "WHERE object_id = ? AND (valid_until IS NULL OR valid_until > ?)")
        with self._lock:
            row = self._db.execute(sql, (object_id, now)).fetchone()
        return _object_from_row(row) if row else None

    def in_bbox(
        self, bbox: BBox, *, layers: Sequence[int] | None = None, types: Sequence[str] | None = None,
        now: float | None = None, limit: int = DEFAULT_LIMIT,
    ) -> list[UdmObject]:
        rows = self._rows_in_boxes([bbox], layers, types, now, limit)
        return [_object_from_row(row) for row in rows]

    def within_radius(
        self, lat: float, lon: float, radius_m: float, *, layers: Sequence[int] | None = None,
        types: Sequence[str] | None = None, now: float | None = None, limit: int = DEFAULT_LIMIT,
    ) -> list[UdmObject]:
        # The circle's bounding boxes prefilter; the limit applies only after the exact distance cut,
        # so the prefilter itself must not be limited.
        rows = self._rows_in_boxes(boxes_around(lat, lon, radius_m), layers, types, now, None)
        near = []
        for row in rows:
            distance = haversine_m(lat, lon, row[5], row[6])
            if distance <= radius_m:
                near.append((distance, row))
        near.sort(key=lambda pair: pair[0])
        return [_object_from_row(row) for _, row in near[:limit]]

    def purge_expired(self, now: float | None = None) -> int:
        now = time.time() if now is None else now
        with self._lock:
            sql = "DELETE FROM objects WHERE valid_until IS NOT NULL AND valid_until <= ?"
            return self._db.execute(sql, (now,)).rowcount

    def count(self) -> int:
        with self._lock:
            return self._db.execute("SELECT count(*) FROM objects").fetchone()[0]

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _rows_in_boxes(
        self, boxes: Sequence[BBox], layers: Sequence[int] | None, types: Sequence[str] | None,
        now: float | None, limit: int | None,
    ) -> list[tuple]:
        now = time.time() if now is None else now
        filters, filter_args = [], []
        if layers:
            filters.append(f"AND o.layer IN ({','.join('?' * len(layers))})")
            filter_args.extend(layers)
        if types:
            filters.append(f"AND o.type IN ({','.join('?' * len(types))})")
            filter_args.extend(types)
        sql = f"""
            SELECT {', '.join('o.' + column.strip() for column in _COLUMNS.split(','))}
            FROM objects_rtree AS r JOIN objects AS o ON o.row_key = r.row_key
            WHERE r.max_lon >= ? AND r.min_lon <= ? AND r.max_lat >= ? AND r.min_lat <= ?
              AND o.lon BETWEEN ? AND ? AND o.lat BETWEEN ? AND ?
              AND (o.valid_until IS NULL OR o.valid_until > ?)
              {' '.join(filters)}
            {'LIMIT ?' if limit is not None else ''}
        """
        rows: list[tuple] = []
        with self._lock:
            for box in boxes:
                args = [box.min_lon, box.max_lon, box.min_lat, box.max_lat]
                args += [box.min_lon, box.max_lon, box.min_lat, box.max_lat, now, *filter_args]
                if limit is not None:
                    args.append(limit - len(rows))
                rows.extend(self._db.execute(sql, args).fetchall())
                if limit is not None and len(rows) >= limit:
                    break
        return rows


def _object_from_row(row: tuple) -> UdmObject:
    (object_id, layer, type_, class_, name, lat, lon, alt, heading, length, width, height,
     created_at, updated_at, valid_until, source) = row
    has_extent = length is not None or width is not None or height is not None
    return UdmObject(
        id=object_id, layer=layer, type=type_, object_class=class_, name=name, lat=lat, lon=lon, alt=alt,
        heading=heading, extent=Extent(length, width, height) if has_extent else None,
        created_at=created_at, updated_at=updated_at, valid_until=valid_until, source=source,
    )
