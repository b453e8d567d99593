"""The grasp geometry the planner needs: from a gear's pose on the table and the tool pose a pick
aims at, the grasp error xi the insertion skill then sees, and back.

A gear lies flat at (x, y, yaw) in the world; the tool points down with its x axis at heading
`tool_yaw`, centred over (tool_x, tool_y). The grasp error (assembly.world.grasp_with_error) is the
gear's offset in the hand from the centred grasp: along the tool's x and y axes [m] and about the
gear's axis [rad]. With the tool frame R_WT = Rz(psi) Rx(pi):

    xi_x = c dx + s dy,  xi_y = s dx - c dy,  xi_yaw = yaw - psi,   d = gear - tool, (c, s) of psi

(the 2 x 2 map [[c, s], [s, -c]] is its own inverse). A gear's yaw is a class modulo its tooth
pitch (`period`), so xi_yaw is wrapped to within period / 2 of a chosen centre (the grasp error
the pick aimed for).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from goflow_common.errors import FileFormatError
from goflow_common.files import read_json


def _wrap(angle: NDArray[np.float64], period: float) -> NDArray[np.float64]:
    return (angle + period / 2) % period - period / 2


def _check_period(period: float) -> None:
    if not (np.isfinite(period) and 0 < period <= 2 * np.pi + 1e-12):
        raise ValueError(f"period = {period}; expected (0, 2 pi] rad")


def grasp_error(
    poses: ArrayLike, tool: ArrayLike, period: float = 2 * np.pi, yaw_centre: float = 0.0
) -> NDArray[np.float64]:
    """The grasp errors xi (N, 3) of gears at world poses `poses` (N, 3) or (3,) = (x, y, yaw)
    picked by a tool at `tool` = (x, y, heading) pointing down; xi_yaw is the member of its class
    (modulo `period`) within period / 2 of `yaw_centre`."""
    _check_period(period)
    p = np.atleast_2d(np.asarray(poses, float))
    t = np.asarray(tool, float)
    if p.shape[1:] != (3,) or t.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(t))):
        raise ValueError(
            f"poses {np.shape(poses)} and tool {np.shape(tool)}; expected finite (N, 3) "
            "and (3,) rows (x [m], y [m], yaw [rad])"
        )
    c, s = np.cos(t[2]), np.sin(t[2])
    dx, dy = p[:, 0] - t[0], p[:, 1] - t[1]
    yaw = yaw_centre + _wrap(p[:, 2] - t[2] - yaw_centre, period)
    return np.column_stack([c * dx + s * dy, s * dx - c * dy, yaw])


def aim_tool(pose: ArrayLike, xi: ArrayLike = (0.0, 0.0, 0.0)) -> NDArray[np.float64]:
    """The tool pose (x, y, heading) at which a gear at `pose` = (x, y, yaw) is held with grasp
    error `xi`: pick there and grasp_error(pose, tool) == xi."""
    p, e = np.asarray(pose, float), np.asarray(xi, float)
    if p.shape != (3,) or e.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(e))):
        raise ValueError(f"pose {np.shape(pose)} and xi {np.shape(xi)}; expected finite (3,) each")
    psi = p[2] - e[2]
    c, s = np.cos(psi), np.sin(psi)
    d = np.array([c * e[0] + s * e[1], s * e[0] - c * e[1]])
    return np.array([p[0] - d[0], p[1] - d[1], psi])


# The pick with the real fingers, measured (benchmarks/grasp_map.py, which writes the file with its
# command, date and commit; 45 simulated picks, every gear lifted): the fingers close along the
# tool's y axis and centre the gear there whatever the aim (residual mean, std); along the tool's
# x axis the gear keeps the aimed error plus a small push (mean, std); its yaw keeps the aimed one
# plus (mean, std). Per gear, SI units.
PICK_MODEL_FILE = Path(__file__).parent / "data" / "pick_model.json"
_AXES = ("closing", "along", "yaw")


def _is_number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x))


def load_pick_model(path: str | os.PathLike[str] = PICK_MODEL_FILE) -> dict[str, dict[str, tuple[float, float]]]:
    """{gear: {"closing" | "along" | "yaw": (mean, std)}} from a pick-model file (strict JSON:
    {"pick_model": {gear: {axis: [mean, std >= 0]}}, ...}, as `benchmarks.grasp_map --model`
    writes it). FileNotFoundError if missing; FileFormatError naming the file and the first bad
    entry otherwise."""
    data = read_json(path, "pick-model file (benchmarks/grasp_map.py --model)")
    table = data.get("pick_model") if isinstance(data, dict) else None
    if not isinstance(table, dict) or not table:
        raise FileFormatError(f'{path}: expected {{"pick_model": {{gear: {{axis: [mean, std]}}}}}}')
    model: dict[str, dict[str, tuple[float, float]]] = {}
    for gear, axes in table.items():
        ok = (
            isinstance(axes, dict)
            and set(axes) == set(_AXES)
            and all(
                isinstance(v, list) and len(v) == 2 and all(_is_number(x) for x in v) and v[1] >= 0
                for v in axes.values()
            )
        )
        if not ok:
            raise FileFormatError(
                f"{path}: pick_model[{gear!r}] = {axes!r}; expected {{axis: [mean, std >= 0]}} "
                f"for the axes {list(_AXES)}"
            )
        model[str(gear)] = {axis: (float(axes[axis][0]), float(axes[axis][1])) for axis in _AXES}
    return model


PICK_MODEL: dict[str, dict[str, tuple[float, float]]] = load_pick_model()


def picked_grasp_errors(
    gear: str, poses: ArrayLike, tool: ArrayLike, period: float, rng: np.random.Generator, yaw_centre: float = 0.0
) -> NDArray[np.float64]:
    """Grasp errors (N, 3) after the real fingers' pick of `gear` at world poses `poses` by a tool
    aimed at `tool`: the geometric errors (grasp_error) with the measured pick (PICK_MODEL): the
    closing axis (tool y) centred, a push along tool x, a small yaw change."""
    if gear not in PICK_MODEL:
        raise ValueError(f"unknown gear {gear!r}; expected one of {sorted(PICK_MODEL)}")
    xi = grasp_error(poses, tool, period, yaw_centre)
    model = PICK_MODEL[gear]
    n = len(xi)
    xi[:, 0] += rng.normal(*model["along"], n)
    xi[:, 1] = rng.normal(*model["closing"], n)
    xi[:, 2] += rng.normal(*model["yaw"], n)
    return xi


__all__ = ["PICK_MODEL", "PICK_MODEL_FILE", "aim_tool", "grasp_error", "load_pick_model", "picked_grasp_errors"]
