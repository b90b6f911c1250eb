"""Views: cameras in every format project ground-truth points onto the right pixels; the exact maps are exact;
the Mitsuba sensor sees what the OpenCV camera describes; the images look like a plant."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from plantbench.cameras import Camera, look_at, read_cameras
from plantbench.capture.views import place_cameras, view_directions
from tests.capture.conftest import SETTINGS, plant_distance


def _maps(case, i):
    depth = np.load(case / "views" / "depth" / f"{i:04d}.npy")
    inst = np.array(Image.open(case / "views" / "instance" / f"{i:04d}.png"))
    return depth, inst


def _targets(plant):
    """Leaf centroids (expected instance 2 + id, on the surface) and skeleton nodes (instance 1, inside the tube:
    the surface in front of them is up to one radius closer)."""
    leaf_pts = np.array([lf.centroid for lf in plant.leaves])
    leaf_inst = np.array([2 + lf.id for lf in plant.leaves])
    sk = plant.skeleton
    pts = np.concatenate([leaf_pts, sk.positions[1:]])  # node 0 is the root at the ground
    inst = np.concatenate([leaf_inst, np.ones(len(sk) - 1, int)])
    slack = np.concatenate([np.zeros(len(leaf_pts)), 1.05 * sk.radii[1:]])
    return pts, inst, slack


def _check_projection(case, plant, project):
    """``project(view, points) -> (uv OpenCV pixels, z)``; every unoccluded point must land within 0.5 px of a pixel
    with its instance id. Returns how many (view, point) pairs were checked.

    Unoccluded: the depth map at the point's pixel agrees with the point's depth within 0.3 pixel footprints (a ray
    within half a pixel of a surface point meets the same surface that close when it is inclined by < ~30 degrees;
    other points are not checked), or for skeleton nodes, lies up to one branch radius in front of the node.
    """
    pts, inst, slack = _targets(plant)
    cams, _ = read_cameras(case / "views" / "cameras.json")
    checked = 0
    for i in range(SETTINGS.views):
        depth, imap = _maps(case, i)
        uv, z = project(i, pts)
        uv_cv, z_cv = cams[i].project(pts)
        assert np.allclose(uv, uv_cv, atol=1e-6) and np.allclose(z, z_cv, rtol=1e-9)  # same pixel convention
        tol = 0.3 * z / cams[i].K[0, 0]
        pix = np.round(uv).astype(int)
        inside = (z > 0) & (pix[:, 0] >= 0) & (pix[:, 1] >= 0) & (pix[:, 0] < imap.shape[1]) & (pix[:, 1] < imap.shape[0])
        for k in np.flatnonzero(inside):
            u, v = pix[k]
            d = depth[v, u]
            unoccluded = z[k] - slack[k] - tol[k] <= d <= z[k] + tol[k]
            if unoccluded:
                assert np.all(np.abs(uv[k] - pix[k]) <= 0.5)
                assert imap[v, u] == inst[k], (i, k, imap[v, u], inst[k])
                checked += 1
    return checked


def test_cameras_json_projects_onto_instances(captured):
    case, plant = captured
    cams, names = read_cameras(case / "views" / "cameras.json")
    assert names == [f"{i:04d}.png" for i in range(SETTINGS.views)]
    checked = _check_projection(case, plant, lambda i, p: cams[i].project(p))
    assert checked >= 0.2 * SETTINGS.views * (len(plant.leaves) + len(plant.skeleton) - 1)


def test_colmap_model_projects_onto_instances(captured):
    import PIL.Image  # noqa: F401  (before pycolmap: zlib clash, docs/design.md, Platform notes)
    import pycolmap

    case, plant = captured
    rec = pycolmap.Reconstruction(str(case / "views" / "colmap"))
    by_name = {im.name: im for im in rec.images.values()}

    def project(i, pts):
        im = by_name[f"{i:04d}.png"]
        cam = rec.cameras[im.camera_id]
        xc = np.array([im.cam_from_world() * p for p in pts])
        uv = np.array([cam.img_from_cam(x) for x in xc])  # COLMAP pixels: centre of (u, v) at (u + .5, v + .5)
        return uv - 0.5, xc[:, 2]

    assert _check_projection(case, plant, project) > 0


def test_transforms_json_projects_onto_instances(captured):
    case, plant = captured
    doc = json.loads((case / "views" / "transforms.json").read_text())
    assert doc["camera_model"] == "OPENCV" and len(doc["frames"]) == SETTINGS.views

    def project(i, pts):  # nerfstudio: OpenGL camera-to-world, rays through pixel index + 0.5
        frame = doc["frames"][i]
        assert frame["file_path"] == f"images/{i:04d}.png"
        c2w = np.array(frame["transform_matrix"])
        xc = (pts - c2w[:3, 3]) @ c2w[:3, :3]  # camera coordinates, OpenGL axes (+y up, looking down -z)
        depth = -xc[:, 2]
        x = doc["fl_x"] * xc[:, 0] / depth + doc["cx"]
        y = -doc["fl_y"] * xc[:, 1] / depth + doc["cy"]
        return np.stack([x, y], 1) - 0.5, depth

    assert _check_projection(case, plant, project) > 0


def test_pycolmap_cameras_and_poses_match_cameras_json(captured):
    import PIL.Image  # noqa: F401
    import pycolmap

    case, _ = captured
    cams, names = read_cameras(case / "views" / "cameras.json")
    rec = pycolmap.Reconstruction(str(case / "views" / "colmap"))
    assert rec.num_reg_images() == len(cams)
    by_name = {im.name: im for im in rec.images.values()}
    for cam, name in zip(cams, names):
        im = by_name[name]
        pose = im.cam_from_world()
        assert np.allclose(pose.rotation.matrix(), cam.R, atol=1e-9)
        assert np.allclose(pose.translation, cam.t, atol=1e-9)
        c = rec.cameras[im.camera_id]
        assert (c.width, c.height) == (cam.width, cam.height)
        assert np.allclose(c.calibration_matrix(), cam.K + np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]))
    # points3D: ground-truth points, each seen in >= 2 images where pycolmap reprojects them onto their 2D points
    assert rec.num_points3D() > 100
    errs = []
    for p in rec.points3D.values():
        assert p.track.length() >= 2
        for el in p.track.elements:
            im = rec.images[el.image_id]
            errs.append(np.linalg.norm(im.project_point(p.xyz) - im.points2D[el.point2D_idx].xy))
    assert np.max(errs) < 1e-6


def test_depth_backprojects_onto_the_mesh(captured):
    case, plant = captured
    cams, _ = read_cameras(case / "views" / "cameras.json")
    pts = []
    for i, cam in enumerate(cams):
        depth, inst = _maps(case, i)
        v, u = np.nonzero(inst > 0)
        assert np.all(np.isfinite(depth[v, u]))
        xc = np.stack([u, v, np.ones(len(u))], 1) @ np.linalg.inv(cam.K).T * depth[v, u, None]
        pts.append((xc - cam.t) @ cam.R)  # R^T (xc - t)
    pts = np.concatenate(pts)
    assert len(pts) > 500
    pts = pts[np.random.default_rng(0).permutation(len(pts))[:3000]]
    dist = plant_distance(plant, pts)
    assert np.median(dist) < 1e-3
    assert np.percentile(dist, 99) < 5e-3


def test_background_depth_is_inf_and_ground_finite(captured):
    case, _ = captured
    saw_sky = saw_ground = False
    for i in range(SETTINGS.views):
        depth, inst = _maps(case, i)
        assert depth.dtype == np.float32 and inst.dtype == np.uint16
        assert np.all(np.isfinite(depth[inst > 0]))
        saw_sky |= bool(np.isinf(depth).any())
        saw_ground |= bool(((inst == 0) & np.isfinite(depth)).any())
    assert saw_sky and saw_ground


def test_normals_face_the_camera(captured):
    case, _ = captured
    cams, _ = read_cameras(case / "views" / "cameras.json")
    n = np.load(case / "views" / "normal" / "0000.npy")
    _, dirs = cams[0].pixel_rays()
    hit = np.linalg.norm(n, axis=-1).ravel() > 0
    assert np.allclose(np.linalg.norm(n.reshape(-1, 3)[hit], axis=1), 1, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", n.reshape(-1, 3)[hit], dirs[hit]) <= 1e-6)


def test_images_look_like_a_plant(captured):
    """Leaves green (with variation between leaves), bark brown, ground textured, plant centred and lit."""
    case, _ = captured
    leaf_means, wood, ground_std, centres = [], [], [], []
    for i in range(SETTINGS.views):
        rgb = np.asarray(Image.open(case / "views" / "images" / f"{i:04d}.png"), float)
        _, inst = _maps(case, i)
        assert rgb.shape == (SETTINGS.height, SETTINGS.width, 3)
        for k in np.unique(inst[inst >= 2]):
            if (inst == k).sum() >= 4:
                leaf_means.append(rgb[inst == k].mean(0))
        wood.append(rgb[inst == 1])
        g = rgb[(inst == 0)].mean(axis=1)
        ground_std.append(g.std())
        v, u = np.nonzero(inst > 0)
        centres.append([u.mean() / inst.shape[1], v.mean() / inst.shape[0]])
    leaf_means = np.array(leaf_means)
    assert len(leaf_means) > 10
    assert np.median(leaf_means[:, 1] - leaf_means[:, 0]) > 5 and np.median(leaf_means[:, 1] - leaf_means[:, 2]) > 5
    assert np.std(leaf_means[:, 1]) > 3  # per-leaf variation
    w = np.concatenate(wood).mean(0)
    assert w[0] > w[2] + 10 and w.mean() > 30  # brown and lit
    assert np.min(ground_std) > 5  # textured
    assert np.all(np.abs(np.array(centres) - 0.5) < 0.2)


def test_mitsuba_sensor_rays_project_to_pixel_centres():
    """The Mitsuba sensor built from an OpenCV camera (off-centre principal point, non-square image) emits, at the
    film position of pixel (u, v)'s centre, a ray that projects through the OpenCV camera to (u, v)."""
    from plantbench.backend import load_mitsuba
    from plantbench.capture.scene import sensor_dict

    mi = load_mitsuba()
    base = look_at([4.0, -3.0, 2.5], [0.0, 0.2, 1.0], fov_x_deg=50, width=40, height=30)
    K = base.K.copy()
    K[0, 2] += 3.25
    K[1, 2] -= 2.0
    cam = Camera(K, base.R, base.t, 40, 30)
    sensor = mi.load_dict(sensor_dict(mi, cam, spp=1))
    v, u = np.mgrid[0:30, 0:40]
    u, v = u.ravel(), v.ravel()
    pos = np.stack([(u + 0.5) / 40, (v + 0.5) / 30], 1)
    if mi.variant().startswith("llvm"):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(pos[:, 0], pos[:, 1]), mi.Point2f(0.5, 0.5))
        o = np.array(ray.o.numpy()).T if np.asarray(ray.o.numpy()).shape[0] == 3 else np.asarray(ray.o.numpy())
        d = np.array(ray.d.numpy()).T if np.asarray(ray.d.numpy()).shape[0] == 3 else np.asarray(ray.d.numpy())
    else:
        rays = [sensor.sample_ray(0.0, 0.5, mi.Point2f(*p), mi.Point2f(0.5, 0.5))[0] for p in pos]
        o = np.array([list(r.o) for r in rays])
        d = np.array([list(r.d) for r in rays])
    uv, z = cam.project(o + 3.0 * d)
    assert np.all(z > 0)
    assert np.max(np.abs(uv - np.stack([u, v], 1))) < 2e-3


def test_rendered_image_agrees_with_the_instance_map(captured, tmp_path):
    """Render the scene dict with Mitsuba's own AOV integrator (shape index) and compare with the exact maps."""
    from plantbench.backend import load_mitsuba
    from plantbench.capture.scene import scene_dict
    from plantbench.io.plantio import read_plant

    mi = load_mitsuba()
    case, _ = captured
    plant, _ = read_plant(case)
    cams, _ = read_cameras(case / "views" / "cameras.json")
    d = scene_dict(plant, cams[:2], SETTINGS, np.random.default_rng(0), mi=mi)
    d["integrator"] = {"type": "aov", "aovs": "si:shape_index"}
    scene = mi.load_dict(d)
    names = [s.id() for s in scene.shapes()]
    code = {"ground": 0, "branches": 1, "leaves": 2}
    for i in range(2):
        aov = np.asarray(mi.render(scene, sensor=i, spp=16))[..., -1]
        shape = np.rint(aov).astype(int)  # 1-based index into scene.shapes(), 0 = miss
        rendered = np.array([-1] + [code[n] for n in names])[shape]
        _, inst = _maps(case, i)
        exact = np.minimum(inst, 2).astype(int)
        exact[np.isinf(_maps(case, i)[0])] = -1
        assert np.mean(rendered == exact) > 0.97


def test_view_directions_cover_the_band():
    d = view_directions(20, (5.0, 45.0))
    el = np.degrees(np.arcsin(d[:, 2]))
    assert np.all((el > 5) & (el < 45))
    az = np.sort(np.arctan2(d[:, 1], d[:, 0]))
    gaps = np.diff(np.concatenate([az, [az[0] + 2 * np.pi]]))
    assert gaps.max() < 2 * (2 * np.pi / 20)  # no big hole in azimuth


@pytest.mark.parametrize("fill", [0.6, 0.9])
def test_place_cameras_fill_the_frame(rng, fill):
    pts = rng.normal(0, 1, (2000, 3)) * [0.8, 1.2, 2.0] + [0.3, -0.2, 2.0]
    cams = place_cameras(pts, 7, elevation=(0.0, 60.0), fov_x_deg=45, width=120, height=90, fill=fill)
    for cam in cams:
        uv, z = cam.project(pts)
        assert np.all(z > 0)
        half = np.array([cam.width, cam.height]) / 2
        off = np.abs(uv - (np.array([cam.width, cam.height]) - 1) / 2) / half
        assert off.max() <= fill + 1e-9
        assert off.max() > fill - 1e-3  # tight on at least one axis


def test_denoised_render_is_closer_to_a_converged_one(captured):
    """A denoising capture's colour (the path tracer at 2 spp, the guides from the separate ``aov`` integrator,
    Open Image Denoise) lies closer to a 64 spp render of the same view than the raw 2 spp render does; the guides are
    the albedo (in [0, 1]) and unit shading normals of the surfaces the instance map says are there."""
    from plantbench.backend import load_mitsuba
    from plantbench.capture.scene import GUIDES_INTEGRATOR, scene_dict
    from plantbench.capture.views import render_colour
    from plantbench.io.plantio import read_plant

    mi = load_mitsuba()
    case, _ = captured
    plant, _ = read_plant(case)
    cams, _ = read_cameras(case / "views" / "cameras.json")
    scene = mi.load_dict(scene_dict(plant, cams[:1], SETTINGS, np.random.default_rng(0), mi=mi))
    guides = mi.load_dict(GUIDES_INTEGRATOR)
    aux = np.asarray(mi.render(scene, sensor=0, spp=2, seed=3, integrator=guides))
    _, inst = _maps(case, 0)
    hit = inst >= 1
    assert aux.shape[-1] == 6
    assert np.all((aux[..., :3] >= -1e-6) & (aux[..., :3] <= 1 + 1e-6))
    assert np.median(np.abs(np.linalg.norm(aux[..., 3:6][hit], axis=-1) - 1.0)) < 1e-3
    reference = render_colour(scene, 0, spp=64, seed=11, mi=mi)
    noisy = render_colour(scene, 0, spp=2, seed=3, mi=mi)
    denoised = render_colour(scene, 0, spp=2, seed=3, mi=mi, guides=guides)
    assert denoised.shape == noisy.shape == reference.shape
    err = [float(np.sqrt(np.mean((np.clip(x, 0, 1) - np.clip(reference, 0, 1))[hit] ** 2))) for x in (noisy, denoised)]
    assert err[1] < 0.7 * err[0], err
