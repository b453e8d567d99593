"""planning.BeliefDrawer: the planner's beliefs drawn in Meshcat, apart from its decisions.

Each gear on the table is drawn as its belief's mean pose (a thin disc of the gear's tip radius)
and its 3-sigma x-y region (a translucent disc around it); a gear in the hand or inserted is
removed. `BeliefDrawer` is a Drake system reading the planner's `beliefs` output port and redrawing
when they change; `draw_beliefs` draws one set of beliefs.
"""

from __future__ import annotations

from collections.abc import Mapping

from pydrake.common.value import AbstractValue
from pydrake.geometry import Cylinder, Meshcat, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import Context, EventStatus, LeafSystem

from assembly.gearset import gear_spec
from planning.domain import GearBelief

#: Where the beliefs live in the Meshcat tree ("beliefs/<gear>/mean", "beliefs/<gear>/region").
PREFIX = "beliefs"
#: The discs' height above the world origin [m] (on the table's top, under the gears' faces).
DISC_Z = 0.0222


def draw_beliefs(meshcat: Meshcat, beliefs: Mapping[str, GearBelief]) -> None:
    """Draw each gear of `beliefs` in `meshcat`: on the table, its mean pose and 3-sigma x-y disc
    (at beliefs/<gear>/mean and beliefs/<gear>/region); elsewhere (hand, inserted), nothing (its
    path is deleted)."""
    for gear, b in beliefs.items():
        path = f"{PREFIX}/{gear}"
        if b.location != "table":
            meshcat.Delete(path)
            continue
        r = gear_spec(gear).tip_radius
        X = RigidTransform(RotationMatrix.MakeZRotation(b.mean[2]), [b.mean[0], b.mean[1], DISC_Z])
        meshcat.SetObject(f"{path}/mean", Cylinder(r, 0.0004), Rgba(0.1, 0.4, 1.0, 0.8))
        meshcat.SetTransform(f"{path}/mean", X)
        meshcat.SetObject(f"{path}/region", Cylinder(r + 3 * max(b.std[:2]), 0.0002), Rgba(0.1, 0.4, 1.0, 0.25))
        meshcat.SetTransform(f"{path}/region", X)


class BeliefDrawer(LeafSystem):
    """Input `beliefs` (gear -> GearBelief, the planner's); every `period` seconds, when they
    differ from the last drawn, `draw_beliefs` draws them in `meshcat`. ValueError if `period`
    is not > 0."""

    def __init__(self, meshcat: Meshcat, period: float) -> None:
        super().__init__()
        if not period > 0:
            raise ValueError(f"period = {period}; expected > 0 s")
        self.set_name("belief_drawer")
        self.meshcat = meshcat
        self._drawn: dict[str, GearBelief] = {}  # what Meshcat shows now (a visualizer's own record)
        self.DeclareAbstractInputPort("beliefs", AbstractValue.Make({}))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)

    def _publish(self, context: Context) -> EventStatus:
        beliefs = self.GetInputPort("beliefs").Eval(context)
        if beliefs != self._drawn:
            draw_beliefs(self.meshcat, beliefs)
            self._drawn = dict(beliefs)
        return EventStatus.Succeeded()


__all__ = ["BeliefDrawer", "DISC_Z", "PREFIX", "draw_beliefs"]
