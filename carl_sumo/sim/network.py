"""Building the I-80-like network from its plain-XML sources with the wheel's netconvert.

``carl_sumo/networks/i80/`` holds the sources (``i80.nod.xml``, ``i80.edg.xml``, ``i80.con.xml``) and the
netconvert options (``i80.netccfg``); ``carl_sumo/networks/i80.net.xml`` is what netconvert makes of them.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from carl_sumo.errors import InputError
from carl_sumo.files import atomic_path, check_xml
from carl_sumo.resources import NETWORKS

NET_SOURCES = NETWORKS / "i80" / "i80.netccfg"
NET_FILE = NETWORKS / "i80.net.xml"


def netconvert_binary() -> str:
    """Path of netconvert: the eclipse-sumo wheel's, else one on PATH."""
    try:
        import sumo

        candidate = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
        if candidate.is_file():
            return str(candidate)
    except ImportError:
        pass
    found = shutil.which("netconvert")
    if not found:
        raise InputError("netconvert not found; install the eclipse-sumo wheel (pip install -e .)")
    return found


def build_network(config: Path = NET_SOURCES, out: Path = NET_FILE) -> Path:
    """Run netconvert on ``config`` and write the network atomically to ``out``."""
    config, out = Path(config).resolve(), Path(out).resolve()
    if not config.is_file():
        raise InputError(f"netconvert configuration {config} does not exist; give the .netccfg "
                         "beside the plain-XML sources (carl_sumo/networks/i80/i80.netccfg)")
    binary = netconvert_binary()
    # netconvert writes a temporary file; it moves into place once it parses as a whole network
    with atomic_path(out, verify=lambda tmp: check_xml(tmp, f"netconvert's network {out}")) \
            as tmp:
        result = subprocess.run([binary, "-c", str(config), "-o", str(tmp)],
                                capture_output=True, text=True, cwd=config.parent)
        if result.returncode != 0 or not tmp.is_file():
            message = (result.stderr or result.stdout).strip().splitlines()
            raise InputError(f"netconvert failed on {config}: "
                             f"{message[-1] if message else 'no output'}")
    return out


def network_body(path: Path) -> str:
    """The network XML without netconvert's header comment (date, paths): for comparing builds."""
    return re.sub(r"<!--.*?-->", "", Path(path).read_text(), count=1, flags=re.S).strip()
