"""ROS 1 (.bag) and ROS 2 (folder with metadata.yaml, .db3, .mcap) bags through the ``rosbags`` library.

Fixes come from every topic of type sensor_msgs/NavSatFix (fixes with status -1, "no fix", are dropped) or
sbg_driver/SbgGpsPos (SBG Systems INS). A bag written by ROS carries its message definitions; where a ROS 2
bag does not, the standard types come from rosbags' type store and SbgGpsPos from the definition below.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.traces.trace import Trace

NAVSATFIX = "sensor_msgs/msg/NavSatFix"
SBG_GPS_POS = "sbg_driver/msg/SbgGpsPos"
SBG_GPS_POS_STATUS = "sbg_driver/msg/SbgGpsPosStatus"

# Interface definitions of sbg_driver (SBG Systems' ROS driver, field lists only).
SBG_GPS_POS_STATUS_MSG = """\
uint8 status
uint8 type
uint8 ifm
uint8 spoofing
uint8 osnma
bool gps_l1_used
bool gps_l2_used
bool gps_l5_used
bool glo_l1_used
bool glo_l2_used
"""
SBG_GPS_POS_MSG = """\
std_msgs/Header header
uint32 time_stamp
SbgGpsPosStatus status
uint32 gps_tow
float64 latitude
float64 longitude
float64 altitude
float32 undulation
geometry_msgs/Vector3 position_accuracy
uint8 num_sv_tracked
uint8 num_sv_used
uint16 base_station_id
uint16 diff_age
"""


def is_bag(path: Path) -> bool:
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    return path.suffix.lower() in (".bag", ".db3", ".mcap")


def sbg_types() -> dict:
    """The sbg_driver types for ``Typestore.register``."""
    from rosbags.typesys import get_types_from_msg

    types = {}
    types.update(get_types_from_msg(SBG_GPS_POS_STATUS_MSG, SBG_GPS_POS_STATUS))
    types.update(get_types_from_msg(SBG_GPS_POS_MSG, SBG_GPS_POS))
    return types


def default_typestore():
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.LATEST)
    store.register(sbg_types())
    return store


def _stamp(message) -> float:
    header = getattr(message, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return np.nan
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def read_bag(path: str) -> Trace:
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    name = str(path)
    bag = Path(path)
    if bag.is_file() and bag.suffix.lower() in (".db3", ".mcap") and (bag.parent / "metadata.yaml").exists():
        bag = bag.parent
    rows = []
    try:
        with AnyReader([bag], default_typestore=default_typestore()) as reader:
            connections = [c for c in reader.connections if c.msgtype in (NAVSATFIX, SBG_GPS_POS)]
            if not connections:
                types = sorted({c.msgtype for c in reader.connections})
                raise InputError(f"no sensor_msgs/NavSatFix or sbg_driver/SbgGpsPos topic in the bag "
                                 f"(types: {', '.join(types) or 'none'})", file=name)
            for connection, timestamp, raw in reader.messages(connections=connections):
                message = reader.deserialize(raw, connection.msgtype)
                stamp = _stamp(message)
                t = stamp if np.isfinite(stamp) and stamp > 0 else timestamp * 1e-9
                if connection.msgtype == NAVSATFIX:
                    if int(message.status.status) < 0:
                        continue
                    accuracy = _navsat_accuracy(message)
                    rows.append((t, message.latitude, message.longitude, message.altitude, accuracy))
                else:
                    sigma = message.position_accuracy
                    rows.append((t, message.latitude, message.longitude, message.altitude,
                                 float(np.hypot(sigma.x, sigma.y))))
    except InputError:
        raise
    except (AnyReaderError, Ros1Error, Ros2Error, OSError, ValueError, KeyError, IndexError, TypeError) as error:
        # rosbags' own errors, plus what a truncated record or an unknown message type raises
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise InputError(f"cannot read the bag: {reason}", file=name) from None
    if not rows:
        raise InputError("the trace has no fixes (empty trace)", file=name)
    rows.sort(key=lambda row: row[0])
    t, lat, lon, alt, accuracy = (np.array(column, dtype=float) for column in zip(*rows))
    return Trace.build(lat, lon, "rosbag", name, t=t, alt=alt, accuracy=accuracy)


def _navsat_accuracy(message) -> float:
    """Horizontal 1-sigma accuracy from a known or diagonal covariance (NaN when unknown)."""
    if int(message.position_covariance_type) == 0:
        return np.nan
    covariance = np.asarray(message.position_covariance, dtype=float)
    return float(np.sqrt(max(covariance[0], 0.0) + max(covariance[4], 0.0)))
