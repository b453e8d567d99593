"""Convert the real Panda log of Gaz et al. (RA-L 2019) into the project's robot-log format.

Reads the folder copied from the authors' repository (default: ../shared/data/panda-gaz2019 beside
the repository root) and writes `data/panda-gaz2019/`: `log.npz` (sim2real.log.save_log), the
authors' `LICENSE` unchanged and a `README.md` with the attribution and how the file was made.

    .venv/bin/python tools/convert_gaz2019.py [--source DIR] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script from a checkout
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from goflow_common.errors import GoflowError  # noqa: E402
from goflow_common.files import check_output_dir, write_atomic  # noqa: E402
from sim2real.importers import GAZ_FILES, read_gaz_layout  # noqa: E402
from sim2real.log import RobotLog, save_log, with_meta  # noqa: E402

DEFAULT_SOURCE = ROOT.parent / "shared/data/panda-gaz2019"
DEFAULT_OUT = ROOT / "data/panda-gaz2019"
REPOSITORY = "marcocognetti/FrankaEmikaPandaDynModel"
COMMIT = "24d85ce4e648e2e894c832bfeee9b16711eb1a1a"
FOLDER = "matlab/data/Exciting_Traj/Trajectory_1"
AUTHORS = "C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca"
TITLE = (
    "Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible Parameters Using "
    "Penalty-Based Optimization"
)
CITATION = f'{AUTHORS}, "{TITLE}", IEEE Robotics and Automation Letters 4(4), 2019'
COMMAND = ".venv/bin/python tools/convert_gaz2019.py"


def readme(log: RobotLog, npz_bytes: int) -> str:
    """The README of the converted folder: attribution, fields, conversion."""
    dt = np.diff(log.time)
    return f"""# Real Franka Emika Panda log (Gaz et al., RA-L 2019), project format

Measurements from a real Panda arm with no hand mounted, recorded while it tracked a Fourier
exciting trajectory for dynamic identification, converted to the project's robot-log format
(`sim2real.log`, docs/sim2real.md "The robot log").

## Attribution

- Authors: {AUTHORS}.
- Paper: "{TITLE}", IEEE Robotics and Automation Letters 4(4), 2019 (cite it when you use this log).
- Source: https://github.com/{REPOSITORY}, commit {COMMIT}, folder `{FOLDER}/`.
- License: GPL-3.0 (the authors' `LICENSE`, copied unchanged beside this file). The converted
  `log.npz` is a derived work under the same license.

## log.npz

{log.n_samples} samples of the 7 joints, t = {log.time[0]:g} .. {log.time[-1]:g} s, about 1 kHz (steps
{dt.min() * 1e3:.2f} .. {dt.max() * 1e3:.2f} ms, median {np.median(dt) * 1e3:.3f} ms); {npz_bytes / 1e6:.2f} MB.
Load it with `sim2real.importers.load_log("data/panda-gaz2019/log.npz")`.

| field | shape | unit | from |
|---|---|---|---|
| time | ({log.n_samples},) | s | rbt_log/{GAZ_FILES["time"]} |
| q | ({log.n_samples}, 7) | rad | rbt_log/{GAZ_FILES["q"]} (measured joint positions) |
| dq | ({log.n_samples}, 7) | rad/s | rbt_log/{GAZ_FILES["dq"]} (measured joint velocities) |
| tau | ({log.n_samples}, 7) | N m | rbt_log/{GAZ_FILES["tau"]} (measured link-side torques tau_J) |

There are no commanded torques or targets, tool poses, wrenches, gripper widths or phase labels
in this log (those fields are absent). Meta: robot `franka_panda`, end_effector `none`,
torque_side `link` (the torque sensors sit after the gearbox, so rotor inertia does not show in
`tau`), joint_names panda_joint1..7, units, source (the URL above), license, citation, and
`commanded_trajectory`: the start pose q0 (gen_q0.txt) and the 5-harmonic Fourier coefficients a
and b per joint (gen_params.txt) with omega_f = 0.15 pi rad/s and a description of the formula.
The sampled command (gen_dq.txt on gen_time.txt) is not converted.

## How it was converted

`{COMMAND}` (options `--source DIR`, default `../shared/data/panda-gaz2019` beside the repository
root, and `--out DIR`, default `data/panda-gaz2019`) reads the four text files with
`sim2real.importers.read_gaz_layout` (one number per line; 7 lines per sample, joint 1..7),
validates the log (shapes, finite values, strictly increasing time, plausible units) and writes it
with `sim2real.log.save_log`: float64 arrays, compressed, no value changed. The text files hold
4 to 6 significant digits; float64 keeps them exactly as parsed.
"""


def convert(source: Path, out: Path) -> Path:
    """Read the Gaz et al. folder `source`, write `out`/log.npz, LICENSE and README.md; returns the npz path."""
    license_path = source / "LICENSE"
    if not license_path.is_file():
        raise FileNotFoundError(f"no LICENSE in {source}; expected the authors' GPL-3.0 license beside the log")
    log = read_gaz_layout(source)
    # the authors' README: the arm carried no hand (a stated end effector, not the layout's guess)
    log = dataclasses.replace(log, meta={k: v for k, v in log.meta.items() if k != "end_effector_assumed"})
    log = with_meta(
        log,
        end_effector="none",
        source=f"https://github.com/{REPOSITORY}/tree/{COMMIT}/{FOLDER}",
        license="GPL-3.0",
        citation=CITATION,
        converted_by=COMMAND,
    )
    check_output_dir(out, "output folder")
    npz = save_log(log, out / "log.npz")
    write_atomic(out / "LICENSE", license_path.read_bytes())
    write_atomic(out / "README.md", readme(log, npz.stat().st_size))
    return npz


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=Path, default=DEFAULT_SOURCE, help="the copied folder (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        npz = convert(args.source, args.out)
    except (GoflowError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {npz} ({npz.stat().st_size / 1e6:.2f} MB), LICENSE and README.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
