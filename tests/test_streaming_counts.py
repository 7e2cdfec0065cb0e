"""The report's counts of a build's SUMO network and OpenDRIVE file are streaming passes: memory stays flat
however large the file. Columbus's 126 MB network was held as a whole lxml tree (1,471 MiB, the build's peak in
the report stage); now 160 MiB, most of it the file's bytes."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

EDGES = 60_000
JUNCTIONS = 20_000


def _sumo_net(path: Path) -> None:
    with open(path, "w", encoding="utf-8") as out:
        out.write('<net version="1.20"><location netOffset="0,0" convBoundary="0,0,100,100" '
                  'origBoundary="9,53,10,54" projParameter="!"/>\n')
        out.writelines(f'<edge id="e{k}" from="a" to="b"><lane id="e{k}_0" index="0" speed="13.89" length="100" '
                      f'shape="0,0 100,0"/><lane id="e{k}_1" index="1" speed="13.89" length="100" '
                      f'shape="0,3 100,3"/></edge>\n' for k in range(EDGES))
        out.write('<junction id="a" type="priority" x="0" y="0"/><tlLogic id="t"/></net>\n')


def _opendrive(path: Path) -> None:
    road = ('<road id="{k}" length="10" junction="-1"><planView><geometry s="0" x="0" y="0" hdg="0" length="10">'
            '<line/></geometry></planView><lanes><laneSection s="0"><center><lane id="0" type="none"/></center>'
            '<right><lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>'
            '</laneSection></lanes><signals><signal id="s{k}" s="1" t="0"/></signals></road>\n')
    with open(path, "w", encoding="utf-8") as out:
        out.write('<OpenDRIVE><header revMajor="1" revMinor="6"/>\n')
        out.writelines(road.format(k=k) for k in range(EDGES))
        # junctions after the roads, as netconvert writes them: a city's are tens of thousands of connections
        links = "".join(f'<laneLink from="-{n}" to="-{n}"/>' for n in range(1, 4))
        for k in range(JUNCTIONS):
            connections = "".join(f'<connection id="{n}" incomingRoad="{k}" connectingRoad="{k + 1}" '
                                  f'contactPoint="start">{links}</connection>' for n in range(6))
            out.write(f'<junction id="j{k}">{connections}</junction>\n')
        out.write('</OpenDRIVE>\n')


def _peak_growth_mib(code: str) -> tuple[float, str]:
    """(peak RSS growth of running ``code`` in a fresh interpreter after its imports, its stdout)."""
    script = textwrap.dedent('''
        import resource, sys
        from tavf_mapkit.pipeline.summary import opendrive_counts
        from tavf_mapkit.sumonet import check_sumo_net
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        ''') + code + textwrap.dedent('''
        print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024)
        ''')
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    *lines, growth = done.stdout.strip().splitlines()
    return float(growth), "\n".join(lines)


def test_sumo_net_counts_stream(tmp_path):
    net = tmp_path / "big.net.xml"
    _sumo_net(net)
    size_mib = net.stat().st_size / 2**20
    growth, out = _peak_growth_mib(f"n = check_sumo_net({str(net)!r}); print(n['edges'], n['lanes'], n['junctions'], "
                                   "n['traffic_lights'])")
    assert out == f"{EDGES} {2 * EDGES} 1 1"
    # the file's bytes are read whole (and a BOM/comment check copies at most once); a tree would be ~10x them
    assert growth < 3 * size_mib + 30, (growth, size_mib)


def test_opendrive_counts_stream(tmp_path):
    xodr = tmp_path / "big.xodr"
    _opendrive(xodr)
    size_mib = xodr.stat().st_size / 2**20
    growth, out = _peak_growth_mib(f"print(opendrive_counts({str(xodr)!r}))")
    assert out == str({"roads": EDGES, "junctions": JUNCTIONS, "signals": EDGES, "objects": 0,
                       "road_length_km": EDGES * 10 / 1000})
    assert growth < 0.5 * size_mib + 30, (growth, size_mib)  # read as it goes: a tree would be several times it
