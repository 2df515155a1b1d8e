"""The mixed-traffic study: human and CACC vehicles on the whole freeway against the CACC
penetration rate. Imports ``experiments`` and below.

``from carl_sumo.study import StudyConfig, run_one`` reads the names of :mod:`carl_sumo.study.run`.
"""


def __getattr__(name: str):
    import importlib

    if name.startswith("__"):
        raise AttributeError(name)
    try:
        return getattr(importlib.import_module("carl_sumo.study.run"), name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
