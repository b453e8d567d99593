"""The real camera's model: its depth noise law, quantisation, scale, occlusion shadow, colour
noise, bad parameters, and the station's noisy image ports."""

import numpy as np
import pytest

from assembly.rgbd_sensor import D405, D415, IDEAL, CameraSensor, RgbdSensorModel, occlusion_shadow, sensor_model


def test_depth_rms_follows_the_stereo_law_and_the_noise_matches_it() -> None:
    z = 0.6
    expected = z**2 * 0.08 / (D415.focal_px * 0.055)
    assert D415.depth_rms(z) == pytest.approx(expected)
    flat = np.full((200, 300), z, np.float32)
    model = RgbdSensorModel("t", baseline=0.055, focal_px=D415.focal_px, subpixel=0.08)
    _, d = model.corrupt(np.zeros((200, 300, 3), np.uint8), flat, 500.0, np.random.default_rng(0))
    assert np.nanstd(d - z) == pytest.approx(expected, rel=0.05)


def test_depth_is_quantised_scaled_and_clipped_to_its_range() -> None:
    depth = np.array([[0.05, 0.3004, np.nan, 0.6]], np.float32)
    rgb = np.zeros((1, 4, 3), np.uint8)
    model = RgbdSensorModel("t", baseline=0.05, focal_px=600.0, depth_unit=0.001, depth_range=(0.1, 0.55))
    _, d = model.corrupt(rgb, depth, 500.0, np.random.default_rng(0), scale=1.0)
    assert np.isnan(d[0, 0]) and np.isnan(d[0, 2]) and np.isnan(d[0, 3])  # too near, missing, too far
    assert d[0, 1] == pytest.approx(0.300, abs=1e-6)
    _, d = model.corrupt(rgb, depth, 500.0, np.random.default_rng(0), scale=1.01)
    assert d[0, 1] == pytest.approx(0.303, abs=1e-6)


def test_occlusion_shadow_lies_left_of_a_near_step_and_has_the_disparity_width() -> None:
    z = np.full((1, 100), 0.6)
    z[0, 50:] = 0.5  # a near surface on the right half
    f_b = 600.0 * 0.05
    shadow = occlusion_shadow(z, np.isfinite(z), f_b)
    width = f_b / 0.5 - f_b / 0.6  # 10 px
    assert shadow[0, 50:].sum() == 0
    assert abs(int(shadow[0, :50].sum()) - width) <= 1
    assert shadow[0, 50 - int(width) + 1 : 50].all()


def test_colour_noise_keeps_dtype_and_an_ideal_model_changes_nothing() -> None:
    rgb = np.full((50, 50, 3), 128, np.uint8)
    depth = np.full((50, 50), 0.5, np.float32)
    out, _ = D415.corrupt(rgb, depth, 500.0, np.random.default_rng(1))
    assert out.dtype == np.uint8 and 2.0 < np.std(out.astype(float)) < 4.5
    out_f, _ = D415.corrupt(rgb / 255.0, depth, 500.0, np.random.default_rng(1))
    assert out_f.dtype == np.float64 and out_f.max() <= 1.0
    same_rgb, same_depth = IDEAL.corrupt(rgb, depth, 500.0, np.random.default_rng(1))
    assert IDEAL.is_ideal and not D405.is_ideal
    np.testing.assert_array_equal(same_rgb, rgb)
    np.testing.assert_array_equal(same_depth, depth)


def test_bad_parameters_name_the_value() -> None:
    with pytest.raises(ValueError, match="baseline"):
        RgbdSensorModel("bad", baseline=-0.01)
    with pytest.raises(ValueError, match="depth_range"):
        RgbdSensorModel("bad", depth_range=(0.5, 0.1))
    with pytest.raises(ValueError, match="extrinsic_std"):
        RgbdSensorModel("bad", extrinsic_std=(0.001, -1.0))
    with pytest.raises(ValueError, match="'d999'"):
        sensor_model("d999")
    with pytest.raises(ValueError, match="scale"):
        CameraSensor(D415, scale=3.0)


def test_the_station_reports_the_real_cameras_images() -> None:
    from assembly.station import StationConfig, build_station

    with pytest.raises(ValueError, match="sensors"):
        StationConfig(sensors={"nope": CameraSensor(D415)})
    station = build_station(StationConfig(sensors={"scene": CameraSensor(D415, 1.0, 3)}))
    diagram = station.diagram
    context = diagram.CreateDefaultContext()
    depth = diagram.GetOutputPort("scene_depth").Eval(context).data[:, :, 0]
    again = diagram.GetOutputPort("scene_depth").Eval(context).data[:, :, 0]
    finite = np.isfinite(depth)
    assert finite.mean() > 0.5
    np.testing.assert_array_equal(depth[finite], again[finite])  # a frame is its time's
    mm = depth[finite] * 1000
    assert np.allclose(mm, np.round(mm), atol=1e-3)  # the D415's 1 mm depth unit
