"""The tiny rendered fly-by the fly-by sweep and dataset tests share: Itokawa at 128 x 128 px,
15 mm, 2 spp, 3 frames 0.2 s apart around closest approach (5 km at 0.5 km/s), seed 3."""

from __future__ import annotations

from starnav.config import Scenario, scenario_from_dict


def tiny_flyby(phase_deg: float = 60.0) -> Scenario:
    """The tiny fly-by at Sun phase ``phase_deg`` at closest approach."""
    return scenario_from_dict({
        "camera": {"width": 128, "height": 128, "focal_length_mm": 15.0},
        "render": {"spp": 2},
        "target": {"kind": "shape_model", "model": "itokawa"},
        "trajectory": {"source": "flyby", "cadence_s": 0.2, "frames": 3,
                       "flyby": {"closest_approach_km": 5.0, "v_inf_km_s": 0.5,
                                 "phase_at_ca_deg": phase_deg, "start_s": -0.2}},
        "pointing": {"moon_offset": "fixed", "roll": "fixed"},
        "detector": {"exposure_time_s": 3e-5}, "seed": 3})
