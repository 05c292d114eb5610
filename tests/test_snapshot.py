"""Cloth.snapshot / Cloth.restore (native/snapshot.c): the whole simulation state as a blob.

* A cloth restored from a snapshot taken mid-tear (tips running, tears started, handles pulling,
  contacts set) steps bit for bit as the original: positions, velocities, topology, stats after
  many more steps. This also finds a scalar field of tc_cloth the snapshot forgot.
* A bad blob (another version, truncated, one byte flipped, a wrong length, not bytes at all)
  raises InvalidInputError naming the problem and leaves the cloth as it was.
"""
import struct

import numpy as np
import pytest

from meshes import sheet
from tearcloth import Cloth, material
from tearcloth.cloth import InvalidInputError


def torn_cloth(seed=11):
    V, T = sheet(0.2, 0.1, 31, 16, jitter=0.3, seed=seed)
    mat = material("cotton", young=5e6, poisson=0.3, thickness=5e-4, density=300.0, bending=1e-6,
                   damping_mass=20.0, damping_stiffness=0.0, tear_stress=3e5)
    c = Cloth(V, T, mat, gravity=(0, 0, -9.81), uv=V[:, :2] / [0.2, 0.1], groups={"x": V[:, 0] / 0.2})
    c.set_solver(cg_tolerance=1e-6, cg_max_iterations=400)
    bottom_mid = int(np.argmin(np.abs(V[:, 0] - 0.1) + 10 * V[:, 1]))
    c.scripted_tear(bottom_mid, (0, 1, 0), 0.012)
    hl = c.add_handle(np.flatnonzero(V[:, 0] < 1e-9))
    hr = c.add_handle(np.flatnonzero(V[:, 0] > 0.2 - 1e-9))
    c.set_tearing(True, scan_period=4)
    return c, hl, hr


def drive(c, hl, hr, start, count):
    for i in range(start, start + count):
        s = 1e-4 * i
        c.move_handle(hl, (-s, 0, 0))
        c.move_handle(hr, (s, 0, 0))
        n = c.num_vertices
        # a contact on a few vertices, so the contact arrays are carried too
        c.set_contacts(np.arange(3, dtype=np.int32), np.tile([0.0, 0.0, 1.0], (3, 1)), np.zeros(3))
        c.step(2e-3, 2)
        assert c.num_vertices >= n


def state(c):
    return (np.array(c.positions), np.array(c.velocities), np.array(c.triangles), np.array(c.rest_positions),
            np.array(c.corner_uv), np.array(c.groups), list(c.events().tips))


def test_restored_cloth_steps_bit_for_bit_through_tears():
    c, hl, hr = torn_cloth()
    drive(c, hl, hr, 0, 52)  # the pull tears from step 49 on: tips are running at 52
    st = c.stats()
    assert len(c.events().tips), "the snapshot must be taken while a tear runs"
    blob = c.snapshot()
    copy, _, _ = torn_cloth(seed=3)  # another mesh altogether: restore replaces everything
    copy.restore(blob)
    assert copy.snapshot() == blob
    drive(c, hl, hr, 52, 30)
    drive(copy, hl, hr, 52, 30)
    for a, b in zip(state(c), state(copy)):
        assert np.array_equal(a, b)
    keep = ("fem_seconds", "tear_seconds")
    assert {k: v for k, v in c.stats().items() if k not in keep} == \
        {k: v for k, v in copy.stats().items() if k not in keep}
    assert c.stats()["cuts"] > st["cuts"], "the tear must have run on after the snapshot"
    print(f"snapshot {len(blob)} bytes for {c.num_vertices} vertices")


def test_bad_blobs_are_refused_and_leave_the_cloth_alone():
    c, hl, hr = torn_cloth()
    drive(c, hl, hr, 0, 5)
    blob = c.snapshot()
    before = state(c)

    def refused(data, words):
        with pytest.raises(InvalidInputError) as e:
            c.restore(data)
        assert any(w in str(e.value) for w in words), str(e.value)
        for a, b in zip(before, state(c)):
            assert np.array_equal(a, b)

    refused(b"", ["truncated"])
    refused(blob[:20], ["truncated"])
    refused(blob[:-1], ["truncated"])
    refused(blob[: len(blob) // 2], ["truncated"])
    refused(blob + b"\0", ["too long"])
    refused(b"X" + blob[1:], ["not a cloth snapshot"])
    refused(blob[:8] + struct.pack("<I", 99) + blob[12:], ["version 99"])
    flipped = bytearray(blob)
    flipped[len(blob) // 3] ^= 0x40
    refused(bytes(flipped), ["corrupted"])
    # a consistent checksum over a wrong length: the reader's own checks catch it
    longer = bytearray(blob)
    longer[16:24] = struct.pack("<Q", len(blob))
    refused(bytes(longer), ["truncated"])
    with pytest.raises(TypeError):
        c.restore("not bytes")
    other = Cloth(*sheet(0.1, 0.1, 5, 5), material("cotton"))
    with pytest.raises(InvalidInputError, match="vertex groups"):
        other.restore(blob)  # the blob has one vertex group, this cloth none
    c.restore(blob)  # the good one still works
    drive(c, hl, hr, 5, 2)


def test_session_with_collision_resumes_bit_for_bit():
    """A torn sheet falling on a ball with self-collision: the session's state (native snapshot,
    collision tracks, measures, clusters, Embree scenes remade from their build corners, body
    keyframes, time), restored into a session built afresh, steps exactly as the original."""
    import trimesh

    from tearcloth.session import CollisionSettings, Session

    ball = trimesh.creation.icosphere(3, 0.1)

    def build():
        V, T = sheet(0.3, 0.3, 21, 21, jitter=0.3, seed=4)
        V[:, :2] -= 0.15
        V[:, 2] = 0.115
        c = Cloth(V, T, material("cotton", tear_stress=2e6))
        c.set_tearing(True)
        s = Session(c, CollisionSettings(thickness=0.004, self_collision=True))
        s.add_body("ball", ball.vertices, ball.faces)
        return s

    def step(s, i):
        s.set_body_keyframe("ball", ball.vertices + [0.0, 0.0, 2e-4 * i], s.time + 1e-3)
        s.step(1e-3)

    s = build()
    s.cloth.scripted_tear(220, (1.0, 0.2, 0.0), 0.06)
    contacts = 0
    for i in range(70):
        step(s, i)
        contacts += s.last.contacts
    assert contacts > 0 and s.cloth.num_vertices > 441
    blob = s.save_state()
    again = build()
    again.restore_state(blob)
    for i in range(70, 100):
        step(s, i)
        step(again, i)
        assert s.last.contacts == again.last.contacts
    for a, b in zip(state(s.cloth), state(again.cloth)):
        assert np.array_equal(a, b)
    assert s.time == again.time
    print(f"session state {len(blob)} bytes; {s.last.contacts} contacts at the end")
    with pytest.raises(ValueError, match="bodies"):
        Session(Cloth(*sheet(0.3, 0.3, 21, 21, jitter=0.3, seed=4), material("cotton")),
                CollisionSettings()).restore_state(blob)
    with pytest.raises(ValueError, match="corrupted"):
        again.restore_state(blob[:-5] + b"xxxxx")


def test_a_restored_cloth_says_the_material_of_its_snapshot():
    """restore() replaced the core's material but left ``Cloth.material`` as it was, and
    set_material(**changes), which starts from it, then put the old material back under the
    restored state (a denim snapshot restored into a cotton cloth said cotton, and a change of its
    tear stress made it cotton again)."""
    V, T = sheet(0.1, 0.1, 6, 6)
    denim = Cloth(V, T, material("denim"))
    cotton = Cloth(V, T, material("cotton"))
    cotton.restore(denim.snapshot())
    assert cotton.material == material("denim")
    cotton.set_material(tear_stress=2e7)
    assert cotton._c.material()["young"] == material("denim").young  # still denim, only the tear stress changed
    assert cotton.material.tear_stress == 2e7
    # values no preset has: the core's values under a name that says where they came from
    denim.set_material(bending=1e-5)
    cotton.restore(denim.snapshot())
    assert cotton.material.name == "from snapshot"
    assert cotton.material.native_kwargs() == cotton._c.material()
