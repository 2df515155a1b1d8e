"""Where the files carl-sumo ships are found, in a source checkout and an installed wheel alike.

The SUMO network (``carl_sumo/networks``), the vehicle types and default leaders' routes
(``carl_sumo/routes``), the default leader set (``carl_sumo/data``) and the event lists that
recipes name (``carl_sumo/data/event_lists``: training event IDs held out, left out or drawn
more often) are package data. The
shipped policies and tuned gains live in the repository's ``policies/`` folder, which a wheel
installs as ``carl_sumo/shipped`` (pyproject.toml maps one onto the other); :func:`policies_dir`
is whichever of the two this installation has.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

PACKAGE = Path(str(files("carl_sumo")))
NETWORKS = PACKAGE / "networks"
ROUTES = PACKAGE / "routes"
DEFAULT_NET = NETWORKS / "i80.net.xml"
VTYPES_FILE = ROUTES / "vtypes.add.xml"
EVENT_LISTS = PACKAGE / "data" / "event_lists"
"""Lists of event IDs (one a line, ``#`` comments) that recipes name by file name, e.g.
``val_hard_real.txt`` (benchmarks/hard_events.py writes them)."""

PRODUCT = "ca_td3_real_10.pt"
"""The file of the real-plant product (``--controller product``): CA-TD3 setting each vehicle's
time gap, once per run and within the platoon's headway budget, in the multi-predecessor CACC
tuned for the fleet (``mpf-tuned``: ``product-base`` plus the commands of 3 vehicles ahead) at the
product's time gaps (cars 0.6 s, trucks 0.8 s), with its safety layers (policies/README.md)."""

PRESET_POLICIES = {"product": PRODUCT}
"""Controller names that stand for a shipped policy file."""


def policies_dir() -> Path:
    """The shipped policies: ``policies/`` of a source checkout, else the installed copy."""
    checkout = PACKAGE.parent / "policies"
    return checkout if checkout.is_dir() and (PACKAGE.parent / "pyproject.toml").is_file() \
        else PACKAGE / "shipped"


def shipped(text: str, folder: Path) -> str:
    """``text`` as given when such a file exists, else the shipped file of that name in
    ``folder`` when there is one (``--net i80.net.xml``, ``policies/X.pt`` from any folder),
    else ``text`` unchanged (the caller says what is missing)."""
    if Path(text).exists():
        return text
    candidate = folder / Path(text).name
    return str(candidate) if candidate.is_file() else text


def shipped_name(text: str, folder: Path) -> str:
    """The file name of the shipped file of ``folder`` that ``text`` stands for
    (:func:`shipped`: a missing path, or that file itself), else ``text``: how a recipe names
    it, so that it reads the same from any folder and installation."""
    found = Path(shipped(text, folder))
    return found.name if found.is_file() and found.resolve().parent == folder.resolve() else text


def controller_name(name: str) -> str:
    """A controller name with a preset (``product``) or a shipped policy file's name resolved to
    its path; anything else unchanged."""
    if name in PRESET_POLICIES:
        return str(policies_dir() / PRESET_POLICIES[name])
    if name.endswith(".pt"):
        return shipped(name, policies_dir())
    return name
