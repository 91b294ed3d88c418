"""The effects: one module per model term (solver/effect.py says what a module holds), discovered here.

Every module of this package whose name does not start with '_' defines `EFFECT`, an instance of a subclass of
solver.effect.Effect. `EFFECTS` maps names to them in their `order`, whatever the robot kind. An effect is a term
of the model it defines parameters for:
- the NAO's model (solver.model.Model, `parameters(setup)`): the base model (the paper's) is the effects with
  `base = True`, the others are the candidates the diagnostics can add (BASE_EFFECTS, EXTRA_EFFECTS);
- an arm's model (kinds.arm.model.ArmModel, `arm_parameters(arm)`): ARM_MODEL_EFFECTS in their gauge order, the sensors'
  frames always, the others (ARM_EFFECTS) chosen by --effects;
- a differential drive's model (a wheeled kind's joint fit, `drive_parameters()`): DRIVE_EFFECTS, each off unless
  chosen by --effects (pwm_driver among them: a choice of model without a parameter).
`joint_offsets`, `link_lengths` and `elasticity` are terms of the first two.
"""

from __future__ import annotations

import importlib
import pkgutil

from naocal.solver.effect import Effect
from naocal.solver.errors import NaocalError


def _discover() -> dict:
    found = []
    for module in pkgutil.iter_modules(__path__):
        if module.name.startswith("_"):
            continue
        effect = getattr(importlib.import_module(f"{__name__}.{module.name}"), "EFFECT", None)
        if effect is None:
            raise ImportError(f"solver/effects/{module.name}.py defines no EFFECT")
        found.append(effect)
    names = [e.name for e in found]
    if len(set(names)) != len(names):
        raise ImportError(f"two effects share a name: {sorted(names)}")
    return {e.name: e for e in sorted(found, key=lambda e: (e.order, e.name))}


def defines(effect, hook: str) -> bool:
    """Whether the effect defines `hook` (e.g. 'parameters', 'arm_parameters') rather than the base class's."""
    return getattr(type(effect), hook) is not getattr(Effect, hook)


EFFECTS = _discover()
BASE_EFFECTS = tuple(name for name, e in EFFECTS.items() if e.base and defines(e, "parameters"))
EXTRA_EFFECTS = tuple(name for name, e in EFFECTS.items() if not e.base and defines(e, "parameters"))
ALL_EFFECTS = BASE_EFFECTS + EXTRA_EFFECTS
ARM_MODEL_EFFECTS = tuple(sorted((name for name, e in EFFECTS.items() if defines(e, "arm_parameters")),
                                 key=lambda name: (EFFECTS[name].gauge_priority, name)))
ARM_EFFECTS = tuple(name for name in ARM_MODEL_EFFECTS if not EFFECTS[name].arm_always)
DRIVE_EFFECTS = tuple(name for name, e in EFFECTS.items() if defines(e, "drive_parameters"))


def effect(name: str):
    """The effect of the NAO's model called `name`; NaocalError listing the known ones otherwise (an arm's
    effect, e.g. tool, is none of the NAO's)."""
    found = EFFECTS.get(name)
    if found is None or not defines(found, "parameters"):
        raise NaocalError(f"unknown effect '{name}' (known: {', '.join(ALL_EFFECTS)})")
    return found


def comma_list(text: str, option: str) -> list[str]:
    """'a,b' -> ['a', 'b'] (spaces trimmed); NaocalError for an empty name (',,,', 'a,,b', 'a,'): a list that says
    nothing must not silently mean the default."""
    names = [n.strip() for n in text.split(",")]
    if not all(names):
        raise NaocalError(f"{option} {text!r}: an empty name in the list (names are comma separated, e.g. "
                          "elasticity,backlash)")
    return names


def parse_effect_names(text) -> tuple[str, ...]:
    """'elasticity,backlash' (or a list of names) -> ('elasticity', 'backlash'): the candidate effects to add to the
    base model; NaocalError for unknown names and for the base model's own effects."""
    if text is None or text == "":
        return ()
    names = comma_list(text, "--effects") if isinstance(text, str) else [n.strip() for n in text]
    for name in names:
        if name not in EXTRA_EFFECTS:
            hint = " (it is part of the base model)" if name in BASE_EFFECTS else ""
            raise NaocalError(f"unknown effect '{name}'{hint}; known effects: {', '.join(EXTRA_EFFECTS)}")
    return tuple(dict.fromkeys(names))


def owner_of(name: str, setup) -> object | None:
    """The effect whose parameters for `setup` include `name` (None if none)."""
    for e in EFFECTS.values():
        if any(p.name == name for p in e.parameters(setup)):
            return e
    return None


def check_testable(effects, data, where) -> None:
    """NaocalError naming `where` (the dataset) when one of `effects` cannot be fitted on `data` (the effect's own
    reason, e.g. time_lag without joint velocities): before any fit, for identify and diagnose alike."""
    for name in effects:
        reason = EFFECTS[name].untestable_reason(data)
        if reason:
            raise NaocalError(f"{where}: the {name} effect {reason}")
