"""Real captures in (plantbench.capture.importers): scans in every format, georeferenced and in other units, photo
sets with a COLMAP model; round trips through export_scan; every bad input names its file."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from plantbench.cameras import look_at, read_cameras
from plantbench.capture.formats import Tracks, write_colmap_text
from plantbench.capture.importers import (
    UP_AXES,
    export_scan,
    ground_offset,
    import_scan,
    import_views,
    read_case_json,
    rotation_to_z,
    to_local,
    to_source,
    up_rotation,
)
from plantbench.errors import InputError
from plantbench.io.ply import read_points
from tests.metrics.synth import random_tree

UTM = np.array([500_000.0, 5_400_000.0, 300.0])


def tree_cloud(rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    """(n, 3) points on the surface of a random tree (root at the origin), metres."""
    skel = random_tree(rng, 12)
    e = skel.edges
    k = rng.integers(0, len(e), n)
    t = rng.random(n)[:, None]
    a, b = skel.positions[e[k, 0]], skel.positions[e[k, 1]]
    r = skel.radii[e[k, 1]][:, None]
    return a + t * (b - a) + r * rng.normal(size=(n, 3)) / np.sqrt(3)


def y_up_cm(local_m: np.ndarray) -> np.ndarray:
    """Georeferenced source coordinates in cm with Y up: the inverse of --units cm --up y for an offset at UTM."""
    world = local_m + UTM
    return np.stack([world[:, 0], world[:, 2], -world[:, 1]], axis=1) * 100.0


def no_leftovers(parent) -> bool:
    return not [p for p in parent.iterdir() if p.name.startswith(".")]


# ---------------------------------------------------------------------------------------------- the frame


def test_up_rotations_are_proper_and_bring_the_axis_up():
    for key, R in UP_AXES.items():
        axis = -np.eye(3)["xyz".index(key[-1])] if key.startswith("-") else np.eye(3)["xyz".index(key)]
        assert np.isclose(np.linalg.det(R), 1.0) and np.allclose(R @ R.T, np.eye(3))
        assert np.allclose(R @ axis, [0, 0, 1]), key
    assert np.array_equal(up_rotation("+Y"), UP_AXES["y"])
    for u in ([0.1, 0.2, 0.9], [0, 0, -1], [0, 0, 1], [1, 0, 0]):
        R = rotation_to_z(np.array(u, float))
        assert np.isclose(np.linalg.det(R), 1.0) and np.allclose(R @ (np.array(u) / np.linalg.norm(u)), [0, 0, 1])


def test_ground_offset_is_the_stem_base():
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal([3, 4, 0], 0.02, (100, 3)) + [0, 0, 0.05] * rng.random((100, 1)),
                          rng.normal([3, 4, 2], 0.5, (4900, 3))])
    off = ground_offset(pts)
    assert np.allclose(off[:2], [3, 4], atol=0.02) and abs(off[2]) < 0.05


# -------------------------------------------------------------------------------------------------- scans


def test_georeferenced_cm_y_up_keeps_precision(tmp_path, rng):
    local = tree_cloud(rng)
    raw = y_up_cm(local)
    src = tmp_path / "plot.xyz"
    with open(src, "w", encoding="utf-8-sig") as fh:  # byte-order mark, comment, header, extra intensity column
        fh.write("# exported by a scanner\nX Y Z intensity\n")
        np.savetxt(fh, np.c_[raw, rng.integers(0, 255, len(raw))], fmt="%.4f")
    res = import_scan(src, tmp_path / "case", units="cm", up="y")
    case = tmp_path / "case"
    pts, fields = read_points(case / "scan" / "scan.ply")
    assert set(fields) == {"station"} and not fields["station"].any()
    rec = read_case_json(case)
    assert rec == res.record and rec.source.points == len(raw) and rec.source.file == "plot.xyz"
    assert np.allclose(rec.frame.offset, UTM + ground_offset(local), atol=1e-6)
    # float32 in the local frame, float64 offset: the georeferenced source comes back to 0.01 mm
    assert np.abs(to_source(pts, rec.frame) - raw).max() < 1e-3  # cm
    assert np.abs(to_local(raw, rec.frame) - pts).max() < 1e-5  # m
    assert abs(np.percentile(pts[:, 2], 0.5)) < 1e-6 and pts[:, 2].max() > 0.5  # Z up, ground at 0
    stations = json.loads((case / "scan" / "stations.json").read_text())
    assert stations["format"] == "plantbench.scan/1" and stations["stations"] == [] and stations["points"] == len(raw)
    assert case.stat().st_mode & 0o777 == (case / "scan").stat().st_mode & 0o777  # not mkdtemp's 0700


@pytest.mark.parametrize("suffix", [".csv", ".txt", ".ply", ".las", ".laz", ".pcd"])
def test_every_format_gives_the_same_cloud(tmp_path, rng, suffix):
    local = tree_cloud(rng, 500) + [2.0, -1.0, 0.3]
    src = tmp_path / f"tree{suffix}"
    if suffix == ".csv":
        np.savetxt(src, local, fmt="%.9f", delimiter=", ", header="x,y,z", comments="")
    elif suffix == ".txt":
        np.savetxt(src, local, fmt="%.9f", header="// plain text", comments="")
    elif suffix == ".ply":
        from plantbench.io.ply import write_points

        write_points(src, local)
    elif suffix == ".pcd":
        import open3d as o3d

        o3d.io.write_point_cloud(str(src), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(local)))
    else:
        import laspy

        header = laspy.LasHeader(point_format=3, version="1.4")
        header.scales, header.offsets = np.full(3, 1e-5), np.zeros(3)
        las = laspy.LasData(header)
        las.x, las.y, las.z = local.T
        las.write(str(src))
    import_scan(src, tmp_path / "case")
    pts, _ = read_points(tmp_path / "case" / "scan" / "scan.ply")
    rec = read_case_json(tmp_path / "case")
    assert rec.source.format == suffix[1:] and len(pts) == len(local)
    assert np.abs(pts + rec.frame.offset - local).max() < 2e-5


@pytest.mark.parametrize("fmt", [".xyz", ".las", ".laz"])
def test_export_and_reimport(tmp_path, rng, fmt):
    local = tree_cloud(rng, 800)
    src = tmp_path / "plot.xyz"
    np.savetxt(src, y_up_cm(local), fmt="%.4f")
    import_scan(src, tmp_path / "case", units="cm", up="y")
    first = read_points(tmp_path / "case" / "scan" / "scan.ply")[0]
    frame = read_case_json(tmp_path / "case").frame
    # the case frame out and back in: same coordinates once the (near-zero) new offset is undone
    export_scan(tmp_path / "case", tmp_path / f"local{fmt}")
    import_scan(tmp_path / f"local{fmt}", tmp_path / "again")
    again = read_points(tmp_path / "again" / "scan" / "scan.ply")[0]
    off = np.asarray(read_case_json(tmp_path / "again").frame.offset)
    assert np.abs(again + off - first).max() < (6e-5 if fmt != ".xyz" else 2e-6)
    # the source frame (cm, Y up, UTM) out and back in with the same options
    export_scan(tmp_path / "case", tmp_path / f"source{fmt}", frame="source")
    if fmt != ".xyz":
        import laspy

        las = laspy.read(str(tmp_path / f"source{fmt}"))
        assert np.allclose(las.header.scales, 0.01) and las.header.offsets[0] > 4e7  # 0.1 mm in cm, georeferenced
    import_scan(tmp_path / f"source{fmt}", tmp_path / "geo", units="cm", up="y")
    geo = read_case_json(tmp_path / "geo").frame
    back = to_source(read_points(tmp_path / "geo" / "scan" / "scan.ply")[0], geo)
    assert np.abs(back - to_source(first, frame)).max() < 1e-2  # cm
    assert np.abs(back - y_up_cm(local)).max() < 1.5e-2


def test_nonempty_case_is_refused_and_nothing_is_left_behind(tmp_path, rng):
    src = tmp_path / "a.xyz"
    np.savetxt(src, tree_cloud(rng, 50))
    (tmp_path / "case").mkdir()
    (tmp_path / "case" / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty") as err:
        import_scan(src, tmp_path / "case")
    assert str(tmp_path / "case") in str(err.value)
    assert [p.name for p in (tmp_path / "case").iterdir()] == ["keep.txt"]
    (tmp_path / "empty").mkdir()
    import_scan(src, tmp_path / "empty")  # an empty folder is fine
    assert (tmp_path / "empty" / "scan" / "scan.ply").is_file() and no_leftovers(tmp_path)


def _bad_files(tmp_path, rng):
    good = tree_cloud(rng, 30)
    nan = good.copy()
    nan[[3, 7, 11], 1] = np.nan
    files = {
        "empty.xyz": ("", "empty file"),
        "blank.xyz": ("\n  \n", "empty file"),
        "comments.xyz": ("# only\n// comments\nx y z\n", "no numeric rows"),
        "nan.xyz": (nan, "3 of 30 rows have NaN"),
        "inf.csv": ("1,2,3\n" * 12 + "1,inf,3\n", "1 of 13 rows have NaN or infinite"),
        "single.xyz": ("1 2 3\n", "1 point(s); a scan needs at least 10"),
        "nine.xyz": (good[:9], "9 point(s)"),
        "two_columns.xyz": ("1 2\n3 4\n" * 10, "2 column(s); need at least 3"),
        "ragged.xyz": ("1 2 3\n" * 12 + "4 5\n", "fewer than 3 columns"),
        "words.xyz": ("x y z\nnot numbers here\n", "line 2 is not numeric"),
        "half.xyz": ("1.5 2.5 n/a\n" + "1 2 3\n" * 12, "line 1 is not numeric"),
        "nan.ply": (None, "2 of 30 rows have NaN"),
        "broken.las": (b"LASF" + bytes(range(200)), "not a readable LAS/LAZ"),
        "text.las": ("1 2 3\n" * 20, "not a readable LAS/LAZ"),
        "broken.ply": ("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n", "PLY"),
        "broken.pcd": ("# .PCD nonsense\n", "PCD"),
        "tree.obj": (good, "unknown scan format"),
        "tall_mm.xyz": (good * 1500 / np.ptp(good[:, 2]), "a tree 1500 m tall"),  # 1.5 m in mm, read as m
    }
    for name, (content, _) in files.items():
        p = tmp_path / name
        if content is None:
            from plantbench.io.ply import write_points

            bad = good.copy()
            bad[[0, 5], 2] = np.inf
            write_points(p, bad)
        elif isinstance(content, bytes):
            p.write_bytes(content)
        elif isinstance(content, str):
            p.write_text(content)
        else:
            np.savetxt(p, content)
    return {tmp_path / k: v[1] for k, v in files.items()}


def test_bad_scans_name_the_file(tmp_path, rng):
    for path, message in _bad_files(tmp_path, rng).items():
        with pytest.raises(InputError) as err:
            import_scan(path, tmp_path / f"case_{path.stem}")
        text = str(err.value)
        assert str(path) in text and message in text, (path.name, text)
        assert not (tmp_path / f"case_{path.stem}").exists()
    import_scan(tmp_path / "tall_mm.xyz", tmp_path / "ok_mm", units="mm")  # the right units pass
    assert no_leftovers(tmp_path)


def test_3000_m_tree_says_wrong_units(tmp_path, rng):
    src = tmp_path / "mm.xyz"
    local = tree_cloud(rng, 200)
    np.savetxt(src, local * 3000 / np.ptp(local[:, 2]))  # a 3 m tree in mm, read as metres
    with pytest.raises(InputError, match=r"a tree 3000 m tall after --units m .*wrong --units\?") as err:
        import_scan(src, tmp_path / "case")
    assert str(src) in str(err.value)
    with pytest.raises(InputError, match="--units must be one of"):
        import_scan(src, tmp_path / "case", units="inch")
    with pytest.raises(InputError, match="--up must be one of"):
        import_scan(src, tmp_path / "case", up="w")


def test_cli_import_scan(tmp_path, rng):
    src = tmp_path / "tree.xyz"
    np.savetxt(src, tree_cloud(rng, 100) * 1000)
    run = [sys.executable, "-m", "plantbench.cli", "import", "scan"]
    ok = subprocess.run([*run, str(src), "--out", str(tmp_path / "c"), "--units", "mm", "--up", "-y"],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert "100 points from tree.xyz" in ok.stdout and read_case_json(tmp_path / "c").frame.up == "-y"
    bad = subprocess.run([*run, str(src), "--out", str(tmp_path / "d")], capture_output=True, text=True)
    assert bad.returncode == 2 and str(src) in bad.stderr and "wrong --units?" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr


# -------------------------------------------------------------------------------------------------- views


def _ring(n=6, *, width=64, height=48):
    az = 2 * np.pi * np.arange(n) / n
    return [look_at([3 * np.cos(a), 3 * np.sin(a), 1.6], [0.0, 0.0, 0.8], fov_x_deg=55, width=width, height=height)
            for a in az]


def _write_model(folder, cameras, names, points):
    """A COLMAP text model of ``cameras`` with ``points`` seen by the first two views."""
    obs_p = np.repeat(np.arange(len(points)), 2)
    obs_i = np.tile([0, 1], len(points))
    uv = np.array([cameras[i].project(points[[p]])[0][0] for p, i in zip(obs_p, obs_i)])
    tracks = Tracks(points, np.full((len(points), 3), 128, np.uint8), obs_p, obs_i, uv)
    return write_colmap_text(folder, cameras, names, tracks)


@pytest.fixture
def photo_set(tmp_path, rng):
    """(images folder, model folder, cameras, names, world points) of a tiny capture in the case frame."""
    from PIL import Image

    cams = _ring()
    names = [f"IMG_{i:04d}.jpg" for i in range(len(cams))]
    images = tmp_path / "photos"
    images.mkdir()
    for name in names:
        Image.fromarray(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(images / name)
    pts = np.concatenate([rng.normal([0.0, 0.0, 0.9], [0.25, 0.25, 0.4], (300, 3)),
                          rng.normal([0.0, 0.0, 0.02], 0.03, (20, 3))])
    model = _write_model(tmp_path / "sparse", cams, names, pts)
    return images, model, cams, names, pts


def _max_pixel_error(case, cams, pts, to_case):
    got, names = read_cameras(case / "views" / "cameras.json")
    errs = []
    for a, b in zip(cams, got, strict=True):
        uv0, z0 = a.project(pts)
        uv1, z1 = b.project(to_case(pts))
        assert np.all(z0 > 0) and np.all(z1 > 0)
        errs.append(np.abs(uv1 - uv0).max())
    return max(errs), names


def test_views_project_where_the_originals_do(tmp_path, photo_set):
    images, model, cams, names, pts = photo_set
    res = import_views(images, model, tmp_path / "case", scale=1.0, up="z")
    frame = read_case_json(tmp_path / "case").frame
    assert np.allclose(frame.rotation, np.eye(3)) and frame.units_factor == 1.0
    err, got_names = _max_pixel_error(tmp_path / "case", cams, pts, lambda x: x - np.asarray(frame.offset))
    assert err < 1.0 and err < 1e-6  # exact up to rounding: the half-pixel shift of COLMAP is undone
    assert got_names == names and all((tmp_path / "case" / "views" / "images" / n).is_file() for n in names)
    assert (tmp_path / "case" / "views" / "colmap" / "cameras.txt").is_file()
    assert (tmp_path / "case" / "views" / "transforms.json").is_file()
    assert res.record.source.images == len(cams) and res.record.source.points == len(pts)
    assert np.linalg.norm(frame.offset[:2]) < 0.1 and abs(frame.offset[2]) < 0.1  # root near the stem base


def test_views_auto_up_and_scale_undo_an_arbitrary_sfm_frame(tmp_path, photo_set):
    images, _, cams, names, pts = photo_set
    k, t_a = 3.7, np.array([5.0, -2.0, 40.0])
    R_a = rotation_to_z(np.array([0.3, -0.5, 0.8])).T  # model frame: rotated, scaled, shifted
    model_cams = [type(c)(c.K, c.R @ R_a.T, k * (c.t - c.R @ R_a.T @ t_a), c.width, c.height) for c in cams]
    model_pts = k * (pts @ R_a.T + t_a)
    model = _write_model(tmp_path / "sfm", model_cams, names, model_pts)
    res = import_views(images, model, tmp_path / "case", scale=1 / k, up="auto")
    frame = res.record.frame
    err, _ = _max_pixel_error(tmp_path / "case", cams, pts, lambda x: to_local(k * (x @ R_a.T + t_a), frame))
    assert err < 1e-6
    # the case frame is the original one up to a turn about Z and a shift: up and metres recovered
    A = np.stack([to_local(k * ((pts[0] + e) @ R_a.T + t_a), frame) - to_local(k * (pts[0] @ R_a.T + t_a), frame)
                  for e in np.eye(3)], axis=1)
    assert np.allclose(A @ A.T, np.eye(3), atol=1e-9) and np.allclose(A[:, 2], [0, 0, 1], atol=1e-9)
    assert any("up estimated" in a for a in res.record.assumptions)


def test_views_binary_model_and_assumed_scale(tmp_path, photo_set):
    import PIL.Image  # noqa: F401 - before pycolmap
    import pycolmap

    images, model, cams, names, pts = photo_set
    binary = tmp_path / "binary"
    binary.mkdir()
    pycolmap.Reconstruction(str(model)).write_binary(str(binary))
    res = import_views(images, binary, tmp_path / "case", up="z")
    assert any("scale assumed 1" in a for a in res.record.assumptions) and "scale assumed 1" in res.notes[0]
    err, _ = _max_pixel_error(tmp_path / "case", cams, pts, lambda x: x - np.asarray(res.record.frame.offset))
    assert err < 1e-6


def test_views_without_points_use_the_cameras(tmp_path, photo_set):
    images, _, cams, names, pts = photo_set
    model = write_colmap_text(tmp_path / "nopoints", cams, names)
    res = import_views(images, model, tmp_path / "case", up="z")
    assert np.allclose(res.record.frame.offset, [0, 0, 1.6]) and "cameras' centroid" in res.record.origin


def test_views_missing_image_names_it(tmp_path, photo_set):
    images, model, *_ = photo_set
    (images / "IMG_0003.jpg").unlink()
    (images / "IMG_0004.jpg").unlink()
    with pytest.raises(InputError, match=r"missing \(2 of 6 missing\)") as err:
        import_views(images, model, tmp_path / "case")
    assert str(images / "IMG_0003.jpg") in str(err.value)
    assert not (tmp_path / "case").exists() and no_leftovers(tmp_path)


def test_views_distortion_and_bad_models(tmp_path, photo_set):
    images, model, cams, names, pts = photo_set
    text = (model / "cameras.txt").read_text()
    line = next(x for x in text.splitlines() if x.startswith("1 PINHOLE"))
    _, _, w, h, fx, fy, cx, cy = line.split()
    (model / "cameras.txt").write_text(text.replace(line, f"1 OPENCV {w} {h} {fx} {fy} {cx} {cy} 0 0 0 0"))
    import_views(images, model, tmp_path / "zero_distortion", scale=1.0, up="z")  # zero distortion is pinhole
    (model / "cameras.txt").write_text(text.replace(line, f"1 SIMPLE_RADIAL {w} {h} {fx} {cx} {cy} 0.05"))
    with pytest.raises(InputError, match="SIMPLE_RADIAL with distortion") as err:
        import_views(images, model, tmp_path / "case")
    assert str(model) in str(err.value)
    (model / "cameras.txt").write_text(text)
    with pytest.raises(InputError, match="not a COLMAP model") as err:
        import_views(images, tmp_path / "photos", tmp_path / "case")
    assert str(tmp_path / "photos") in str(err.value)
    from PIL import Image

    Image.fromarray(np.zeros((24, 32, 3), np.uint8)).save(images / names[2])
    with pytest.raises(InputError, match="image is 32x24 but its COLMAP camera is 64x48") as err:
        import_views(images, model, tmp_path / "case")
    assert str(images / names[2]) in str(err.value)
    with pytest.raises(InputError, match="--up must be one of"):
        import_views(images, model, tmp_path / "case", up="north")


def test_cli_import_views(tmp_path, photo_set):
    images, model, *_ = photo_set
    out = subprocess.run([sys.executable, "-m", "plantbench.cli", "import", "views", "--images", str(images),
                          "--colmap", str(model), "--out", str(tmp_path / "case")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "scale assumed 1" in out.stdout and "6 registered views" in out.stdout
    (images / "IMG_0000.jpg").unlink()
    out = subprocess.run([sys.executable, "-m", "plantbench.cli", "import", "views", "--images", str(images),
                          "--colmap", str(model), "--out", str(tmp_path / "case2")], capture_output=True, text=True)
    assert out.returncode == 2 and str(images / "IMG_0000.jpg") in out.stderr
