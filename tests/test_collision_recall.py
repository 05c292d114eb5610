"""Recall of the clustered detector against brute force on random deforming scenes at the
artist's time steps (dt = 1 ms and 4.17 ms = 10 sub-steps per 24 fps frame): motions are given in
m/s and rad/s, so the larger step moves everything 4.17x farther per step between full
detections. No collision response: penetrations grow
deep, and every vertex brute force finds deeper than 10 % of the thickness must be found."""
import numpy as np
import pytest

from collision_reference import brute_force_detect  # tests/ is on sys.path (conftest.py)
from tearcloth import settings
from tearcloth.collision import CollisionDetector
from test_collision_detect import body_mesh, grid

TH = settings.default("collision", "thickness")
THRESHOLD = settings.default("collision", "displacement_threshold")


def scene_recall(kind, seed, dt, steps=40):
    rng = np.random.default_rng(seed)
    p0, t = grid(30, 30, 1.0)
    bv, bt = body_mesh(kind)
    det = CollisionDetector(TH, 0.4, THRESHOLD, cluster_size=int(rng.integers(40, 150)))
    det.add_body(bv, bt, "body")
    speed = rng.uniform(0.4, 1.0)  # m/s, mostly up through the cloth
    direction = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 1.0])
    vel = speed * direction / np.linalg.norm(direction)
    spin = rng.uniform(-1.5, 1.5)  # rad/s about z
    wave_k = rng.uniform(2, 6, 2)
    wave_w = rng.uniform(5, 15)  # rad/s: the cloth deforms, not only the body moves
    # the body's top starts 5 mm below the cloth and rises through it by speed x steps x dt
    start = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), -bv[:, 2].max() - 0.005])
    total = found = 0
    for s in range(steps):
        time = (s + 1) * dt
        offset = start + vel * time
        ang = spin * time
        R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
        bpos = bv @ R.T + offset
        det.update_body("body", bpos, velocities=np.tile(vel, (len(bv), 1)))
        p = p0.copy()
        p[:, 2] = 0.03 * np.sin(wave_k[0] * p0[:, 0] + wave_w * time) * np.cos(wave_k[1] * p0[:, 1])
        c = det.detect(p, t)
        ref = brute_force_detect(det, p, t)
        deep = set(ref.vertex[ref.depth > 1.1 * TH].tolist())  # inside by more than 10 % of the thickness
        got = set(c.vertex[c.depth > TH].tolist())
        total += len(deep)
        found += len(deep & got)
    return total, found


@pytest.mark.parametrize("dt", [1e-3, 1.0 / 24 / 10], ids=["dt1ms", "dt4.17ms"])
def test_recall_on_random_deforming_scenes(dt):
    total = found = 0
    for kind, seed in (("sphere", 11), ("box", 12), ("sphere", 13), ("box", 14)):
        t, f = scene_recall(kind, seed, dt)
        total += t
        found += f
    assert total > 200, "the scenes must produce penetrations"
    assert found / total >= 0.999, f"recall {found}/{total}"
