"""The undisturbed reference run of a contact scene (docs/transparency.md, "The reference run"):
the same scene with every network effect removed (links that deliver at once, no buffering, no
codec), run in lockstep when the run itself is, so that its felt force goes into the run's bag
(the run fact `reference_master_force_n`) and the analysis reads it from there, never running a
simulation itself."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import yaml

from haptic_teleop.scene.contact import reference_wanted
from haptic_teleop.scene.schema import LoadedScene, Scene

MAX_REFERENCES = 8
_REFERENCES: dict[str, np.ndarray] = {}  # the reference run's |F_m| per reference scene (YAML text)

# The run fact that holds the reference run's |F_m|, one value per tick (analysis/transparency.py).
REFERENCE_FACT = "reference_master_force_n"


def reference_scene(sc: dict[str, Any]) -> dict[str, Any]:
    """The scene (a resolved scene's mapping) with its network effects removed: links that
    deliver at once, no buffering, no codec."""
    ref = copy.deepcopy(sc)
    for d in ("forward", "backward"):
        ref["network"][d] = {"effects": {}, "buffer": {"policy": "none"}}
    return ref


def reference_force(sc: dict[str, Any]) -> np.ndarray:
    """|F_m| of the undisturbed reference run of scene `sc` (run once per process and scene)."""
    from haptic_teleop.engine.lockstep import COL, Engine
    from haptic_teleop.typedconfig import build

    ref = reference_scene(sc)
    key = yaml.safe_dump(ref, sort_keys=True)
    got = _REFERENCES.get(key)
    if got is None:
        config = build(Scene, ref, "", "reference run")
        engine = Engine(LoadedScene(config=config, source="reference run", raw=ref), loop="auto")
        run = engine.run(handle_sigint=False)
        got = np.abs(run.data[: run.ticks, COL["m_force_n"]])
        if len(_REFERENCES) >= MAX_REFERENCES:  # a sweep's process: keep the newest few
            del _REFERENCES[next(iter(_REFERENCES))]
        _REFERENCES[key] = got
    return got


def reference_facts(scene: LoadedScene) -> dict[str, list[float]]:
    """The run facts of the reference run a recorded run of `scene` carries: {} when the scene's
    analysis does not ask for one (scene/contact.py, `reference_wanted`)."""
    if not reference_wanted(scene.config):
        return {}
    sc = yaml.safe_load(scene.to_yaml())  # the scene exactly as the bag records it
    return {REFERENCE_FACT: reference_force(sc).tolist()}
