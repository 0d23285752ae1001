"""An independent forward simulator: readings made by casting beams at an explicit datum surface.

Written from the physics (issue 12), apart from the measurement model and its effects: nothing
here imports ``metrology.core.model``, ``metrology.core.effects``, the calibration, the diagnosis
or the older simulators, so data drawn here are data the fit's formulas did not make.

Modules: :mod:`.surface` (datum height field), :mod:`.beams` (beam casting), :mod:`.head`
(sensor rings), :mod:`.poses` (poses and pose error), :mod:`.characteristic` (reading error vs
distance), :mod:`.drift` (time, temperature, drift), :mod:`.incidence` (incidence bias),
:mod:`.errors` (noise, gross readings, blanks, periodic error, cross-talk), :mod:`.families`
(the causes and their sizes), :mod:`.outside` (effects outside the catalogue, from their physics),
:mod:`.cases` (blind cases), :mod:`.write` (case files); the
production hole log of ``metro simulate-log``: :mod:`.panels` (flat, sphere, cylinder with
closed-form rays), :mod:`.shapes` (height-field panels: the generated wing skin, barrel, nacelle lip
and saddle; panels off their CAD), :mod:`.torus` (a torus lip, tight across and gentle around), :mod:`.meshes` (panel files ray-cast as meshes; the generated
panels' exports), :mod:`.holes` (hole tables), :mod:`.log_spec` (set-up, faults, chunks), :mod:`.log`
(generation, the cell's own attitude adjustment through a pluggable controller), :mod:`.log_write`
(CSV, partitioned Parquet, truth); :mod:`.properties` (a head's sensor properties acting on its
calibration run and its production log alike, and a calibration run drawn with them).
"""

from metrology.sim.forward.beams import BeamHits, cast_beams
from metrology.sim.forward.cases import Case, draw_case, draw_cases, draw_outside, draw_pair
from metrology.sim.forward.characteristic import Characteristic, draw_curve
from metrology.sim.forward.drift import Drift, TemperatureProfile, draw_drift, draw_temperature, draw_times
from metrology.sim.forward.families import CATALOGUE, FAMILIES, OUT_OF_CATALOGUE, Effect, FamilySpec
from metrology.sim.forward.head import Head, draw_head, perturb_layout
from metrology.sim.forward.incidence import IncidenceBias, draw_incidence
from metrology.sim.forward.holes import HoleTable, read_hole_table
from metrology.sim.forward.log import MicroPlane, simulate_cell, simulate_log
from metrology.sim.forward.log_spec import HoleChunk, LogSpec, SensorDrift, SensorShift
from metrology.sim.forward.log_write import write_log_csv, write_log_parquet
from metrology.sim.forward.meshes import MeshPanel, load_sim_panel, write_generated
from metrology.sim.forward.panels import PANELS, CylinderPanel, FlatPanel, Panel, SpherePanel, make_panel
from metrology.sim.forward.properties import CalibrationRun, HeadProperties, SensorProperty, draw_calibration
from metrology.sim.forward.poses import draw_poses, perturb_poses, tilt_of
from metrology.sim.forward.shapes import GENERATED, GeneratedPanel, HeightPanel, OffCadPanel, generated_panel, \
    parse_off_cad
from metrology.sim.forward.torus import TorusPanel
from metrology.sim.forward.surface import HAND_SCAN, DatumSurface, draw_surface, flat_surface, sample_cloud, sample_hand_scan
from metrology.sim.forward.write import CASE_FILES, write_case

__all__ = [
    "BeamHits", "cast_beams", "Case", "draw_case", "draw_cases", "draw_outside", "draw_pair", "Characteristic", "draw_curve",
    "Drift", "TemperatureProfile", "draw_drift", "draw_temperature", "draw_times", "CATALOGUE", "FAMILIES",
    "OUT_OF_CATALOGUE", "Effect", "FamilySpec", "Head", "draw_head", "perturb_layout", "IncidenceBias",
    "draw_incidence", "draw_poses", "perturb_poses", "tilt_of", "DatumSurface", "draw_surface", "flat_surface",
    "sample_cloud", "sample_hand_scan", "HAND_SCAN", "CASE_FILES", "write_case", "simulate_cell", "simulate_log", "HoleChunk", "LogSpec",
    "SensorDrift", "SensorShift", "write_log_csv", "write_log_parquet", "PANELS", "CylinderPanel", "FlatPanel",
    "Panel", "SpherePanel", "make_panel", "HoleTable", "read_hole_table", "MicroPlane", "MeshPanel", "load_sim_panel",
    "write_generated", "CalibrationRun", "HeadProperties", "SensorProperty", "draw_calibration", "GENERATED", "GeneratedPanel", "HeightPanel", "OffCadPanel", "generated_panel", "parse_off_cad", "TorusPanel",
]
