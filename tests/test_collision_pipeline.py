"""The detector's step in C (native/collide/detect.c, swept.c) against its specification, the
previous release's step (collision_reference.ReferenceDetector: Python over the per-stage kernels,
Embree for bodies): on a recorded simulation - a cloth pulled apart by two handles (it tears) while a
ball pushes into it, with self-collision - both give the same contacts at every step, for every
measure and trip rule; and a detector pickled by the previous release resumes and goes on as that
release would have."""
import pickle

import numpy as np
import pytest
import trimesh

from collision_reference import ReferenceDetector
from tearcloth import Cloth, examples, material
from tearcloth.bench.collision import _Recording
from tearcloth.collision import CollisionDetector
from tearcloth.session import CollisionSettings, Session

DT = 1e-3
SETTINGS = dict(thickness=0.003, friction=0.3, displacement_threshold=0.0015, cluster_size=60)


@pytest.fixture(scope="module")
def torn_cloth_frames():
    """What a session hands its detector over 120 steps of 1 ms (body, cloth, velocities, tears)."""
    m = examples.square_cloth()  # vertical, in the plane y = 0
    V = m.vertices
    c = Cloth(V, m.triangles, material("cotton", tear_stress=3e5), uv=m.loop_uv(), groups=m.groups)
    c.set_tearing(True)
    s = Session(c, CollisionSettings(thickness=SETTINGS["thickness"], cluster_size=SETTINGS["cluster_size"]))
    ball = trimesh.creation.icosphere(2, 0.05)
    base = ball.vertices + [V[:, 0].mean(), 0.055, V[:, 2].mean()]
    s.add_body("ball", base, ball.faces)
    rec = _Recording(s.detector)
    s.detector = rec
    hl, hr = c.add_handle("handle_left"), c.add_handle("handle_right")
    for i in range(120):
        t = (i + 1) * DT
        c.move_handle(hl, (-0.1 * t, 0, 0))
        c.move_handle(hr, (0.1 * t, 0, 0))
        s.set_body_keyframe("ball", base + [0, -0.3 * t, 0], t)  # into the cloth at 0.3 m/s
        s.step(DT)
    assert sum(fr.events is not None for fr in rec.steps) >= 3, "the cloth must tear"
    return rec.steps, ball.faces


def replay(det, frames, faces, start=0, stop=None):
    """Per step: (deepest contacts, every contact) as arrays."""
    if start == 0:
        det.add_body(frames[0].body, faces, "ball")
    out = []
    for fr in frames[start:stop]:
        det.update_body("ball", fr.body, fr.body_velocity)
        c = det.detect(fr.cloth, fr.triangles, fr.velocity, fr.dt)
        a = det.all_contacts
        out.append(tuple(np.array(x, copy=True) for x in (c.vertex, c.depth, c.normal, c.velocity, a.vertex,
                                                           a.depth, a.normal, a.velocity, a.friction)))
        if fr.events is not None:
            det.on_topology(fr.events, fr.after, fr.after_triangles)
    return out


def assert_same(got, want):
    assert len(got) == len(want)
    touching = 0
    for k, (g, w) in enumerate(zip(got, want)):
        for i, (a, b) in enumerate(zip(g, w)):
            assert a.shape == b.shape, f"step {k}, array {i}: {a.shape} vs {b.shape}"
            np.testing.assert_array_equal(a, b, err_msg=f"step {k}, array {i}")
        touching += len(g[4])
    assert touching > 100, "the ball and the cloth's layers must touch"


@pytest.mark.parametrize("measure,trip_rule", [("relative", "paper"), ("relative", "bound"), ("absolute", "paper"),
                                               ("full", "paper")])
def test_pipeline_contacts_equal_the_reference_step(torn_cloth_frames, measure, trip_rule):
    frames, faces = torn_cloth_frames
    kw = dict(SETTINGS, measure=measure, trip_rule=trip_rule)
    got = replay(CollisionDetector(**kw), frames, faces)
    want = replay(ReferenceDetector(**kw), frames, faces)
    assert_same(got, want)


def test_detector_pickled_by_the_previous_release_resumes_as_it_would_have(torn_cloth_frames):
    """The previous release pickled Embree scenes for bodies and the swept stage's former bounds: the
    detector resumes from such a pickle (native trees instead, every swept bound read again) and
    continues with the contacts the previous release's step gives from the same state."""
    frames, faces = torn_cloth_frames
    ref = ReferenceDetector(**SETTINGS)
    replay(ref, frames, faces, 0, 60)
    old = CollisionDetector.__new__(CollisionDetector)
    old.__dict__.update(ref.old_release_state())
    resumed = pickle.loads(pickle.dumps(old))
    assert isinstance(resumed, CollisionDetector) and not isinstance(resumed, ReferenceDetector)
    want_det = pickle.loads(pickle.dumps(ref))
    got = replay(resumed, frames, faces, 60)
    want = replay(want_det, frames, faces, 60)
    assert_same(got, want)
