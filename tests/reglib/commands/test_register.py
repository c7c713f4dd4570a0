"""Tests of the ``reglib register`` command (run in-process through reglib.cli.main)."""
import json

import numpy as np

from reglib import KernelWarp
from reglib.cli import main


def _sets():
    t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    model = np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]
    return model, model * 1.5 + [2.0, -1.0]


def test_text_in_json_out(tmp_path):
    model, target = _sets()
    np.savetxt(tmp_path / "m.txt", model)
    np.savetxt(tmp_path / "t.txt", target)
    assert main(["register", str(tmp_path / "m.txt"), str(tmp_path / "t.txt"), "--out", str(tmp_path / "r.json")]) == 0
    body = json.loads((tmp_path / "r.json").read_text())
    assert set(body) == {"registered", "correspondence", "transform", "converged", "reason", "n_iter", "method",
                         "seed", "fitness", "inlier_rmse", "matrix"}
    assert body["matrix"] is None  # l2e is non-rigid
    assert 0.0 <= body["fitness"] <= 1.0 and body["inlier_rmse"] >= 0.0
    assert (body["method"], body["seed"]) == ("l2e", 0)
    warp = KernelWarp.from_dict(body["transform"])
    assert np.abs(warp(model) - target).max() < 0.01
    assert np.allclose(body["registered"], warp(model))


def test_npy_in_points_out(tmp_path):
    model, target = _sets()
    np.save(tmp_path / "m.npy", model)
    np.save(tmp_path / "t.npy", target)
    out = tmp_path / "reg.npy"
    assert main(["register", str(tmp_path / "m.npy"), str(tmp_path / "t.npy"), "--out", str(out),
                 "--method", "cpd-affine"]) == 0
    assert np.abs(np.load(out) - target).max() < 1e-3
    assert (tmp_path / "reg.json").is_file()


def test_bad_input_exits_2(tmp_path, capsys):
    np.savetxt(tmp_path / "m.txt", np.zeros((10, 2)))
    np.savetxt(tmp_path / "t.txt", np.zeros((10, 3)))
    assert main(["register", str(tmp_path / "m.txt"), str(tmp_path / "t.txt"), "--out", str(tmp_path / "o.json")]) == 2
    assert "dimension" in capsys.readouterr().err
    missing = str(tmp_path / "missing.txt")
    assert main(["register", missing, str(tmp_path / "t.txt"), "--out", str(tmp_path / "o.json")]) == 2


def test_rigid_method_on_a_pcd_scan_with_json_options(tmp_path):
    from reglib.io import write_points

    rng = np.random.default_rng(3)
    model = rng.uniform(-1, 1, (400, 3)) * [1.0, 0.6, 0.3]
    angle = np.deg2rad(20.0)
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    target = model @ rot.T + [0.2, -0.1, 0.05]
    write_points(tmp_path / "m.pcd", model)
    write_points(tmp_path / "t.ply", target)
    out = tmp_path / "r.json"
    assert main(["register", str(tmp_path / "m.pcd"), str(tmp_path / "t.ply"), "--out", str(out),
                 "--method", "icp"]) == 0
    body = json.loads(out.read_text())
    assert body["method"] == "icp"
    assert np.abs(np.asarray(body["registered"]) - target).max() < 1e-3
    assert main(["register", str(tmp_path / "m.pcd"), str(tmp_path / "t.ply"), "--out", str(out),
                 "--method", "icp", "--options", '{"max_iter": "many"}']) == 2


def _ply_with_normals(path, points, normals):
    rows = "\n".join(" ".join(repr(float(v)) for v in row) for row in np.c_[points, normals])
    path.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n"
                    + "".join(f"property double {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
                    + f"end_header\n{rows}\n")


def test_file_normals_a_method_leaves_unused_are_not_an_error(tmp_path):
    # the command passes the clouds it reads: the target file's normals go where the method uses them,
    # and a point-to-point ICP leaves them alone (as a keyword they would be an InputError)
    rng = np.random.default_rng(4)
    model = rng.uniform(-1, 1, (300, 3)) * [1.0, 0.6, 0.3]
    target = model + [0.1, -0.05, 0.02]
    np.save(tmp_path / "m.npy", model)
    np.save(tmp_path / "t.npy", target)
    _ply_with_normals(tmp_path / "t.ply", target, np.tile([0.0, 0.0, 1.0], (300, 1)))
    options = '{"variant": "point_to_point", "init": "given"}'
    for target_file, out in (("t.npy", "plain.json"), ("t.ply", "normals.json")):
        assert main(["register", str(tmp_path / "m.npy"), str(tmp_path / target_file), "--out", str(tmp_path / out),
                     "--method", "icp", "--options", options]) == 0
    plain, with_normals = ((tmp_path / f).read_text() for f in ("plain.json", "normals.json"))
    assert plain == with_normals
    assert np.abs(np.asarray(json.loads(plain)["registered"]) - target).max() < 1e-6


def test_color_gmm_keeps_the_models_colours_and_turns_its_normals_in_the_ply_it_writes(tmp_path):
    from scipy.spatial.transform import Rotation

    from reglib.io import read_point_cloud, write_points

    rng = np.random.default_rng(5)
    xy = rng.uniform(-1, 1, (400, 2))
    model = np.c_[xy * [1.0, 0.7], 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1])]
    colors = rng.integers(0, 256, (400, 3)).astype(np.uint8)
    colors[0], colors[1] = 0, 255
    normals = rng.normal(size=(400, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rot = Rotation.from_euler("z", 25.0, degrees=True).as_matrix()
    shift = np.array([0.3, -0.2, 0.1])
    write_points(tmp_path / "m.ply", model, colors=colors, normals=normals)
    write_points(tmp_path / "t.ply", model @ rot.T + shift, colors=colors)
    out = tmp_path / "r.ply"
    assert main(["register", str(tmp_path / "m.ply"), str(tmp_path / "t.ply"), "--out", str(out),
                 "--method", "color-gmm"]) == 0
    cloud = read_point_cloud(out)
    assert np.array_equal(np.round(cloud.colors * 255).astype(np.uint8), colors)  # every row, in the model's order
    body = json.loads(out.with_suffix(".json").read_text())
    m = np.asarray(body["matrix"])
    assert m.shape == (4, 4)
    np.testing.assert_allclose(cloud.points, model @ m[:3, :3].T + m[:3, 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(m[:3, :3], rot, atol=1e-3)
    np.testing.assert_allclose(m[:3, 3], shift, atol=1e-3)
    np.testing.assert_allclose(cloud.normals, normals @ m[:3, :3].T, atol=1e-9)  # a rotation turns them as points
