"""The attribute tracker without Blender (tearcloth.attributes): the warp direction and its grain
angle, the X-axis fallback without UVs, corner/face/point attributes through a scripted tear, and
torn_time carried over a resumed bake. The Blender round trip is tests/test_blender_attributes.py."""
from __future__ import annotations

import numpy as np
import pytest

from meshes import sheet
from tearcloth import attributes as attrs
from tearcloth.cloth import Cloth
from tearcloth.materials import material


def test_warp_follows_u_turned_by_the_grain_angle_and_falls_back_to_local_x():
    v, t = sheet(0.1, 0.1, 5, 5)          # in the XY plane
    uv = v[:, [1, 0]][t] * 10.0           # u grows along +y, v along +x
    warp = attrs.warp_directions(v, t, uv, np.zeros(len(t)))
    np.testing.assert_allclose(warp, np.tile([0.0, 1.0, 0.0], (len(v), 1)), atol=1e-6)
    n = np.cross(v[t[0, 1]] - v[t[0, 0]], v[t[0, 2]] - v[t[0, 0]])
    turned = attrs.warp_directions(v, t, uv, np.full(len(t), np.pi / 2))
    np.testing.assert_allclose(turned, np.tile(np.cross(n / np.linalg.norm(n), [0, 1, 0]), (len(v), 1)), atol=1e-6)
    rot = np.eye(4)
    rot[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # the object's local X is world +y
    fallback = attrs.warp_directions(v, t, None, np.zeros(len(t)), rot)
    np.testing.assert_allclose(fallback, np.tile([0.0, 1.0, 0.0], (len(v), 1)), atol=1e-6)


def test_tear_carries_attributes_marks_torn_points_and_resumes_torn_time():
    v, t = sheet(0.1, 0.1, 11, 11)
    m = len(t)
    point = attrs.UserAttribute("p", "POINT", "FLOAT", v[:, :1] * 10.0)   # linear in x
    face = attrs.UserAttribute("f", "FACE", "INT", np.arange(m, dtype=float)[:, None])
    # each face's own constant at its corners: sharp across every edge
    corner = attrs.UserAttribute("c", "CORNER", "FLOAT", np.repeat(np.arange(m, dtype=float)[:, None, None], 3, axis=1))
    uv = v[:, :2][t] * 10.0
    groups = attrs.carried_groups(v, [point, face, corner])
    cloth = Cloth(v, t, material("cotton"), uv=uv, groups=groups)
    tracker = attrs.AttributeTracker(v, t, [point, face, corner])
    before = tracker.frame(cloth, 0.0, None, cloth.corner_uv)
    assert before["torn"][2].sum() == 0 and np.all(before["torn_time"][2] == -1)
    assert cloth.scripted_tear(60, (0.37, 1.0, 0.0), 0.03) > 0
    after = tracker.frame(cloth, 0.5, None, cloth.corner_uv)
    x = cloth.positions[:, 0]
    np.testing.assert_allclose(after["p"][2], x * 10.0, atol=1e-12)   # interpolated with the split weights
    tri = cloth.triangles
    rest_centroid = cloth.rest_positions[tri].mean(axis=1)
    faces = after["f"][2]
    np.testing.assert_array_equal(faces[:m], np.arange(m))           # old triangles keep their face
    # the cut split triangles; each new one lies inside the face it came from
    assert len(tri) > m and len(cloth.positions) > len(v)
    assert tracker._bary(rest_centroid, faces).min() > -1e-9
    np.testing.assert_allclose(after["c"][2].reshape(-1, 3), np.repeat(faces[:, None], 3, axis=1))
    torn = after["torn"][2]
    assert torn.sum() >= 4 and np.all(after["torn_time"][2][torn == 1] == 0.5)
    assert np.all(after["torn_time"][2][torn == 0] == -1)
    # resume: a new tracker continues from the last frame's torn_time, and earlier tears keep theirs
    again = attrs.AttributeTracker(v, t, [point, face, corner])
    again.restore_torn_time(after["torn_time"][2])
    later = again.frame(cloth, 1.0, None, cloth.corner_uv)
    np.testing.assert_array_equal(later["torn_time"][2], after["torn_time"][2])


def test_unsupported_types_say_why():
    assert attrs.unsupported("BYTE_COLOR", "POINT") is None  # plays as a float colour
    assert "edge" in attrs.unsupported("FLOAT", "EDGE")
    assert "UV maps" in attrs.unsupported("FLOAT2", "POINT")
    assert attrs.unsupported("FLOAT_COLOR", "CORNER") is None
    with pytest.raises(KeyError):
        attrs.USD_TYPES["STRING"]


def test_primvars_survive_a_rebuilt_root(tmp_path):
    """A truncated root rebuilt from its frame files (issue 12 defect 7) still declares the extra
    primvars, so Blender keeps seeing them and a resumed bake keeps writing them."""
    pytest.importorskip("pxr")
    from tearcloth import cache
    v, t = sheet(0.1, 0.1, 3, 3)
    path = str(tmp_path / "c.usda")
    pv = {"torn": ("FloatArray", "vertex", np.zeros(len(v))),
          "ccol": ("Color4fArray", "faceVarying", np.ones((3 * len(t), 4))),
          "UV2": ("TexCoord2fArray", "faceVarying", np.zeros((3 * len(t), 2)))}
    with cache.CacheWriter(path, "M", 24.0, object_name="M", uv_name="UVMap") as w:
        for f in (1, 2):
            w.write_frame(f, v, t, corner_uv=v[:, :2][t], primvars=pv)
    declared = cache.cache_info(path)["primvars"]
    with open(path, "r+") as f:
        f.truncate(40)
    assert cache.damaged_root(path)
    assert cache.repair_root(path, "M") == [1, 2]
    info = cache.cache_info(path)
    assert info["primvars"] == declared and info["uv_name"] == "UVMap" and info["has_uv"]
    np.testing.assert_array_equal(cache.read_primvars(path, 2)["ccol"], np.ones((3 * len(t), 4)))


def test_a_resumed_bake_keeps_when_each_point_tore(tmp_path):
    """Bake frames 1-3 with a weak cloth that tears at once, resume to 5: the points torn before the
    resume keep their torn_time, the cache keeps one set of primvars, and the carried face
    attribute still names each triangle's face."""
    pytest.importorskip("pxr")
    import dataclasses

    from tearcloth import cache
    from tearcloth.bake import BakeJob
    from test_bake_job import bake, inputs, plan_for

    def weak(frames, resume=False):
        plan = plan_for(tmp_path, frames)
        plan.material = dataclasses.replace(plan.material, tear_stress=2e4)
        plan.attributes = [attrs.UserAttribute("face", "FACE", "INT", np.arange(len(plan.triangles), dtype=float)[:, None])]
        plan.resume = resume
        return plan

    bake(weak((1, 3)))
    path = str(tmp_path / "Sheet.usda")
    before = cache.read_primvars(path, 3)
    assert before["torn"].sum() > 0, "the weak sheet should have torn by frame 3"
    job = BakeJob(weak((1, 5), resume=True))
    assert job.start_frame == 3
    job.begin(inputs(3, job.plan))
    while not job.done:
        job.advance(inputs(job.next_frame, job.plan))
    job.close()
    assert cache.cache_info(path)["frames"] == [1, 2, 3, 4, 5]
    after = cache.read_primvars(path, 5)
    torn_before = np.flatnonzero(before["torn_time"] >= 0)
    np.testing.assert_array_equal(after["torn_time"][torn_before], before["torn_time"][torn_before])
    assert np.all(after["torn_time"][after["torn"] == 1] <= 4 / 24 + 1e-6)
    m0 = len(job.plan.triangles)
    np.testing.assert_array_equal(after["face"][:m0], np.arange(m0))


def test_grain_angle_face_attribute_overrides_the_material():
    """``tearcloth_grain_angle`` (FACE, radians) replaces the material's grain angle where set."""
    v, t = sheet(0.1, 0.1, 4, 4)
    uv = v[:, :2][t] * 10.0                              # u along +x
    grain = attrs.UserAttribute(attrs.GRAIN_ATTRIBUTE, "FACE", "FLOAT", np.full((len(t), 1), np.pi / 2))
    cloth = Cloth(v, t, material("cotton"), uv=uv, groups=attrs.carried_groups(v, [grain]))
    plain = attrs.AttributeTracker(v, t, [], grain_angle=0.0).frame(cloth, 0.0, None, cloth.corner_uv)
    override = attrs.AttributeTracker(v, t, [grain], grain_angle=0.0).frame(cloth, 0.0, None, cloth.corner_uv)
    np.testing.assert_allclose(plain["warp"][2], np.tile([1.0, 0.0, 0.0], (len(v), 1)), atol=1e-6)
    normal = np.cross(v[t[0, 1]] - v[t[0, 0]], v[t[0, 2]] - v[t[0, 0]])
    turned = np.cross(normal / np.linalg.norm(normal), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(override["warp"][2], np.tile(turned, (len(v), 1)), atol=1e-6)


def test_attributes_follow_a_removed_fragment_that_renumbers_the_rest():
    # Regression: the tracker knew triangles and points by index; a removed fragment renumbers
    # what is left (fragment.c), and a denim bake on bpy 4.2 failed with "operands could not be
    # broadcast together with shapes (1603,3,3) (1606,3,3)". Now they are known by their carried
    # rest positions: after cutting off a corner (removed) and a tear elsewhere, every face keeps
    # its own value, corners stay sharp and earlier torn points keep when they tore.
    v, t = sheet(0.1, 0.1, 11, 11)
    m = len(t)
    face = attrs.UserAttribute("f", "FACE", "INT", np.arange(m, dtype=float)[:, None])
    corner = attrs.UserAttribute("c", "CORNER", "FLOAT", np.repeat(np.arange(m, dtype=float)[:, None, None], 3, axis=1))
    cloth = Cloth(v, t, material("cotton"), uv=v[:, :2][t] * 10.0, groups=attrs.carried_groups(v, [face, corner]))
    cloth.set_tearing(True, min_fragment_area=1e-4)  # the sheet's cells are 1 cm^2: a corner triangle goes
    tracker = attrs.AttributeTracker(v, t, [face, corner])
    tracker.frame(cloth, 0.0, None, cloth.corner_uv)
    assert cloth.scripted_tear(60, (0.37, 1.0, 0.0), 0.03) > 0
    first = tracker.frame(cloth, 0.5, None, cloth.corner_uv)
    torn_before = {cloth.rest_positions[i].tobytes() for i in np.flatnonzero(first["torn"][2])}
    corner_tri = int(np.flatnonzero((t == 0).any(axis=1))[0])  # the triangle at vertex 0
    a, b = [k for k in t[corner_tri] if k != 0]
    assert cloth.scripted_tear(a, v[b] - v[a], float(np.linalg.norm(v[b] - v[a]))) == 1
    assert cloth.stats()["fragments_removed"] == 1 and cloth.num_triangles < m + 20
    after = tracker.frame(cloth, 1.0, None, cloth.corner_uv)
    tri, rest = cloth.triangles, cloth.rest_positions
    faces = after["f"][2]
    assert len(faces) == len(tri) and corner_tri not in set(faces.tolist())
    assert tracker._bary(rest[tri].mean(axis=1), faces).min() > -1e-9  # each triangle inside its own face
    np.testing.assert_allclose(after["c"][2].reshape(-1, 3), np.repeat(faces[:, None], 3, axis=1))
    times = {rest[i].tobytes(): after["torn_time"][2][i] for i in range(len(rest))}
    assert torn_before and all(times[k] == 0.5 for k in torn_before if k in times)
