"""One <controller> per id: netconvert writes a traffic light's controller once for every junction it controls.

A traffic light program that SUMO joined over several nodes (DLR's TAVF network: joined1, joinedS_21,
joinedS_26) is written as one top-level <controller> per node, each with the same id and the same controls.
Ids must be unique (signals and junctions refer to controllers by id; the ASAM schema rejects duplicates), and
these are one controller: the duplicates are merged into the first, whose controls become the union in order.
"""

from __future__ import annotations

from dataclasses import replace

from tavf_mapkit.opendrive.repair import Repair

#: Repair.action of this repair
MERGED_CONTROLLERS = "merged duplicate controllers"


def repair_controllers(odr):
    """(map with unique controller ids, repairs)."""
    from tavf_mapkit.opendrive.network import OpenDriveMap

    merged: dict = {}
    copies: dict = {}
    for controller in odr.controllers:
        first = merged.get(controller.id)
        if first is None:
            merged[controller.id] = controller
            continue
        copies[controller.id] = copies.get(controller.id, 1) + 1
        extra = [signal for signal in controller.signal_ids if signal not in first.signal_ids]
        merged[controller.id] = replace(first, signal_ids=first.signal_ids + tuple(extra))
    if not copies:
        return odr, []
    repairs = [Repair(MERGED_CONTROLLERS, "", None, f"controller {cid!r} was written {n} times; merged into one "
                                                     f"with {len(merged[cid].signal_ids)} controls")
               for cid, n in copies.items()]
    return OpenDriveMap(odr.header, odr.roads, odr.junctions, tuple(merged.values()), odr.source, odr.warnings,
                        odr.extra_xml), repairs
