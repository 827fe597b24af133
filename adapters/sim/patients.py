"""Patient variation: each simulated session draws its own seal, body wall, incision and
insufflation from documented ranges.

A model trained and tested on one set of trocar parameters flatters the estimator; drawing a
patient per session lets a study test on patients it never trained on. A scenario run without
ranges keeps the effects' defaults (the *fixed patient*: every session is the same patient, as
the committed reports and the tests assume). With :class:`PatientRanges`,
:func:`draw_patient` draws one patient per session from the session's own random stream, so
two sessions with different seeds never share a draw, and the draw is recorded in the
session's metadata (``metadata["patient"]``); :func:`apply_patient` puts it into a model's
effect specs.

Ranges (uniform, independent per parameter; the table and each range's source are in
:class:`PatientRanges`): seal sliding level 0.5 - 2.0 N and breakaway 0.2 - 1.2 N (van den
Dobbelsteen, Schooleman, Dankelman, "Friction dynamics of trocars", Surg Endosc 21:1338,
2007), insufflation 8 - 15 mmHg (EAES pneumoperitoneum guideline, Neudecker et al., Surg Endosc
16:1121, 2002), body wall stiffness 50 - 200 N/m, stiffening 20 - 60 N/m per mmHg and damping
2.5 - 10 N s/m, incision 2 - 5 cm deep and up to 5 mm to the side (assumptions around the
effects' defaults).

The seal's roll parameters move with its insertion ones (each roll value scaled by the same
factor as its insertion value), so the shaft radius that relates them stays the default's.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from wrenchd.models.physics.effects.body_wall import BodyWallParams
from wrenchd.models.physics.effects.seal import SealParams

#: Handle torsional stiffness for contact torques of the paper's size [N m/rad]. Calibrated,
#: not measured: the two-step paper (Wu et al., arXiv 2012.01479, abstract) reports a mean
#: torque RMSE of 0.08 N m and 0.06 - 0.12 N m per axis, so its contact torques are at least
#: of that order. In the ``trocar-contact`` scenario the tip turns a median 0.67 rad
#: (95th percentile 1.5 rad) from its grasp during contact; at 0.25 N m/rad the handle's
#: torque has an RMS of about 0.06 - 0.18 N m per axis over contact samples (0.05 N m/rad,
#: the contact effect's default, gives 0.01 - 0.035 N m).
REALISTIC_HANDLE_NM_PER_RAD = 0.25


def _span(low: float, high: float, what: str):
    return Field(default=(low, high), description=f"{what} (low, high)")


class PatientRanges(BaseModel):
    """Uniform ranges a patient's parameters are drawn from.

    Where each range comes from (draws independent per parameter):

    ====================  ================  ========================================================
    parameter             range             source
    ====================  ================  ========================================================
    seal sliding level    0.5 - 2.0 N       van den Dobbelsteen, Schooleman, Dankelman, "Friction
    (insertion ``fc``)                      dynamics of trocars", Surg Endosc 21:1338 (2007):
                                            sliding friction 0.25 - 3.0 N over six trocars; the
                                            middle of it
    seal breakaway        0.2 - 1.2 N       the same study: fluctuations of 0.2 - 2.5 N at starts
    (``fs_excess``)                         and reversals; the lower half (the LuGre spike adds to
                                            fc)
    insufflation          8 - 15 mmHg       EAES guideline on the pneumoperitoneum (Neudecker et
    pressure                                al., Surg Endosc 16:1121, 2002): the lowest pressure
                                            that gives exposure, 12 - 15 mmHg the usual working
                                            range; 8 mmHg for low-pressure practice
    wall stiffness k0     50 - 200 N/m      assumption: a factor 2 either side of the effect's
                                            default (100 N/m); no in-vivo lateral port stiffness
                                            found
    wall stiffening       20 - 60 N/m/mmHg  assumption: the default (40) +-50 %; in-vivo
                                            insufflation does stiffen the wall (Song, Alijani,
                                            Frank, Hanna, Cuschieri, Surg Endosc 20:987, 2006),
                                            the slope is ours
    wall damping          2.5 - 10 N s/m    assumption: the default (5) halved to doubled
    incision depth        2 - 5 cm          assumption: where the shaft meets the wall along the
                                            shaft, an abdominal wall a few cm thick with the RCM
                                            set inside it
    incision offset       +-5 mm per        assumption: how far the port sits sideways from the
                          lateral axis      RCM (the default is 3 mm, -2 mm)
    ====================  ================  ========================================================
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    seal_fc_n: tuple[float, float] = _span(0.5, 2.0, "seal sliding level, insertion [N]")
    seal_fs_excess_n: tuple[float, float] = _span(0.2, 1.2, "seal breakaway excess [N]")
    pressure_mmhg: tuple[float, float] = _span(8.0, 15.0, "insufflation pressure [mmHg]")
    wall_k0_n_per_m: tuple[float, float] = _span(50.0, 200.0, "wall stiffness at 0 mmHg [N/m]")
    wall_k_per_mmhg: tuple[float, float] = _span(20.0, 60.0, "wall stiffening [N/m per mmHg]")
    wall_damping_ns_per_m: tuple[float, float] = _span(2.5, 10.0, "wall damping [N s/m]")
    incision_depth_m: tuple[float, float] = _span(0.02, 0.05,
                                                  "incision depth along the shaft [m]")
    incision_offset_m: float = Field(default=0.005, ge=0.0,
                                     description="largest sideways offset per lateral axis [m]")

    @model_validator(mode="after")
    def _ordered(self):
        for name, value in self:
            if isinstance(value, tuple) and not (0.0 <= value[0] <= value[1]):
                raise ValueError(f"{name}: need 0 <= low <= high, got {value}")
        return self


def draw_patient(ranges: PatientRanges, rng: np.random.Generator) -> dict[str, dict[str, Any]]:
    """One patient: effect parameters by effect name (``seal_friction``, ``body_wall``).

    Every value is drawn whether or not a scenario has the effect, so a patient's draw does
    not depend on the scenario.
    """
    def u(span: tuple[float, float]) -> float:
        return float(rng.uniform(*span))

    seal_default = SealParams()
    fc, fs = u(ranges.seal_fc_n), u(ranges.seal_fs_excess_n)
    fc_scale = fc / seal_default.fc[0]
    fs_scale = fs / seal_default.fs_excess[0]
    pressure, k0, kp, damping = (u(ranges.pressure_mmhg), u(ranges.wall_k0_n_per_m),
                                 u(ranges.wall_k_per_mmhg), u(ranges.wall_damping_ns_per_m))
    depth = u(ranges.incision_depth_m)
    dx, dy = (float(v) for v in rng.uniform(-ranges.incision_offset_m,
                                            ranges.incision_offset_m, 2))
    return {
        "seal_friction": {"fc": [fc, seal_default.fc[1] * fc_scale],
                          "fs_excess": [fs, seal_default.fs_excess[1] * fs_scale]},
        "body_wall": {"incision_m": [dx, dy, depth], "k0_n_per_m": k0, "k_per_mmhg": kp,
                      "pressure_mmhg": pressure, "damping_ns_per_m": damping},
    }


def fixed_patient() -> dict[str, dict[str, Any]]:
    """The effects' defaults in the layout of :func:`draw_patient` (for the record)."""
    seal, wall = SealParams(), BodyWallParams()
    return {
        "seal_friction": {"fc": list(seal.fc), "fs_excess": list(seal.fs_excess)},
        "body_wall": {"incision_m": list(wall.incision_m), "k0_n_per_m": wall.k0_n_per_m,
                      "k_per_mmhg": wall.k_per_mmhg, "pressure_mmhg": wall.pressure_mmhg,
                      "damping_ns_per_m": wall.damping_ns_per_m},
    }


def apply_patient(effects: list[dict[str, Any]], patient: dict[str, dict[str, Any]]
                  ) -> list[dict[str, Any]]:
    """``effects`` (model-file specs) with the patient's parameters put into the effects it
    names; other effects, and parameters the patient does not name, are left as they are."""
    out = []
    for spec in effects:
        spec = dict(spec)
        if spec["name"] in patient:
            spec["params"] = {**spec.get("params", {}), **patient[spec["name"]]}
        out.append(spec)
    return out
