"""The station diagnosis on an insertion log with a withheld contact effect: it localises the gap
to the contact/insertion phases, names the effect and closes the gap."""

from __future__ import annotations

import dataclasses

import pytest

from sim2real.contact import diagnose_insertion
from sim2real.station_logs import CONTACT_CASE, make_insertion_log, with_sensor_noise


def test_shaft_friction_is_found_in_the_insertion_phase():
    # a grasp error inside the medium skill's feasible set (a flow draw may land near its edge)
    log, _ = make_insertion_log(CONTACT_CASE, gear="medium", xi=(0.0008, -0.0018, 0.04), seed=0)
    d = diagnose_insertion(with_sensor_noise(log), episodes=0)
    s = d.summary()
    assert s["where"]["dominant_phase"] in ("contact", "insertion")
    assert s["where"]["phases"]["approach"]["excess"] < 0.05 * s["where"]["phases"]["insertion"]["excess"]
    assert [r["effect"] for r in s["selected"]][:1] == ["shaft_friction"]
    assert s["selected"][0]["params"]["mu"]["value"] == pytest.approx(1.0, abs=0.2)
    assert s["verdict"]["label"] == "explained"
    assert s["how_far"]["closed_total"] > 0.8


def test_a_log_without_the_station_fields_is_refused():
    log, _ = make_insertion_log({}, gear="medium", seed=0)
    with pytest.raises(ValueError, match="tool_pose"):
        diagnose_insertion(dataclasses.replace(log, tool_pose=None), episodes=0)


def test_cli_station_log_then_diagnose(tmp_path, capsys):
    from goflow_cli import main
    import json

    log = tmp_path / "insertion.npz"
    assert (
        main(["sim2real", "make-log", "--model", "station", "--effect", "shaft_friction=1.0", "--out", str(log)]) == 0
    )
    out = tmp_path / "report"
    assert (
        main(
            [
                "diagnose",
                "--model",
                "station",
                "--log",
                str(log),
                "--out-dir",
                str(out),
                "--episodes",
                "0",
                "--effects",
                "shaft_friction",
                "grasp_slip",
            ]
        )
        == 0
    )
    report = json.loads((out / "report.json").read_text())
    assert report["selected"][0]["effect"] == "shaft_friction"
    assert report["where"]["dominant_phase"] in ("contact", "insertion")
    assert (
        main(
            [
                "sim2real",
                "make-log",
                "--model",
                "station",
                "--effect",
                "shaft_friction=1.0",
                "--out",
                str(tmp_path / "x.csv"),
            ]
        )
        == 2
    )
    assert ".npz" in capsys.readouterr().err
