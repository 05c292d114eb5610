"""Displacement measures that decide, per close cluster pair, full or incremental detection.

This file owns paper section IV-B: per-cluster displacement since the previous step (dis_avg,
dis_dev), cluster AABBs, close pairs by AABB overlap, and the accumulated measures:

* ``RelativeMeasure`` (the paper's): per close pair, RelDis_avg += dis_avg(c1) - dis_avg(c2) and
  RelDis_dev += dis_dev(c1) + dis_dev(c2) (eqs. 1-3); amplitude ||RelDis_avg|| + RelDis_dev
  (eq. 4); over ``displacement_threshold`` -> full detection and reset. A pair that was not close
  at the previous step starts at zero.
* ``AbsoluteMeasure`` (the earlier method the paper compares to): every cluster accumulates its
  own displacement with no pairing; a cluster whose amplitude passes the threshold sends all its
  close pairs to full detection and resets. As in the paper's comparison, an immobile collider
  then costs the same under both measures (only the cloth's own motion counts). Two clusters
  each under the threshold may have moved by up to twice it relative to each other, so the
  detector doubles the tracking margin in this mode (``CollisionDetector.track_range``).
* 'full': every close pair, every step.

A ``RelativeMeasure`` pair's deviation accumulator may start below zero: the detector's clearance
credit (detector.py module docs, "Clearance") - a pair whose full detection found its lines clear
beyond the track range restarts at minus that extra margin, so eq. 4's amplitude passes the
threshold only once the pair has moved by the margin it really has.

Batching (``lookahead``): full detection has a fixed cost per step (vertex normals, one Embree call
and one fit per collider cluster, refinement, merging) that dwarfs its cost per ray. Per-pair
accumulators drift out of phase, so the relative measure left alone triggers a few pairs in almost
every step and pays that fixed cost every step. With ``lookahead`` L > 0, a step in which some
pair (a cluster, for the absolute measure) passes the threshold also runs full detection for the
pairs that, at this step's rate (the amount eq. 4 just added), would pass it within L steps; they
are reset with the others. A full detection earlier than needed is always safe. Measured on the
walking mannequin with L = 3 (the detector's choice, for both measures): full detections in 42
steps of 117 instead of 100, 6 % more pairs detected, the median step 4x and the mean step 1.2-1.4x
cheaper.

Why boxes are inflated by (displacement_threshold + thickness)/2: the paper inflates by
threshold/2 so that two clusters cannot touch before their measure reaches the threshold; a
contact here starts at a distance of ``thickness`` (the cloth's proximity), so the thickness is
added to keep that guarantee.

The trip rule (``TripMeasure``, issue 15; ``CollisionDetector(trip_rule='bound')``): what
matters is whether a vertex can reach the contact distance before the next full detection, so the
measure is a bound on a vertex's motion towards the other cluster, spent against the clearance the
pair's last full detection left, not the paper's mean + deviation against a fixed threshold:

* A full detection of a pair tracks every ray hit within ``track_range``; an untracked vertex was
  then farther than that, so the pair has ``budget = track_range - thickness`` of clearance.
* Each step, per cluster, an affine fit A(x) = t + L (x - c) of its displacement and the largest
  residual e (C: ``cluster_fit``). Per pair, m = max over a's vertices |d_x - A_b(x)| + e_b +
  |L_b| reach, or the same from b's side, whichever is smaller (``pair_motion``): a rigorous bound
  of how much the step changed the distance from any vertex of one cluster to the other's surface
  (measure.c has the derivation). It is a maximum, not a mean plus a deviation, and it drops the
  motion the two clusters share, rotation included: a sleeve on a swinging arm, neighbouring cloth
  clusters turning together, spend only what they move relative to each other.
* ``used`` += m per step; capped by what the boxes prove now (no vertex of a is nearer to b than the
  box gap: ``budget - (gap - thickness)``), which is also where a new pair starts - exact, where the
  paper's "a new pair starts at zero" relies on one step moving less than the threshold.
* full detection when ``used > budget``: before that no untracked vertex can be within the contact
  distance, whatever the time step; the check runs every step on that step's measured motion, so
  a bigger step simply spends the clearance faster. Batching (``lookahead``) as above, on m.

``RelativeMeasure`` (the paper's rule, ``trip_rule='paper'``) stays the default: measured on the
T-shirt simulated on the walking mannequin (bench ``collision.simulated``, 60 steps), the bound
rule fully detects 2.5x (dt 1 ms, moving: share 0.207 vs 0.083) to 3x (immobile) more pairs than
the paper's mean + deviation and costs 1.7-2x its ms - a maximum over ~100 jittering cloth
vertices is about twice their deviation - and at 10 sub-steps per frame both detect nearly every
pair every step (0.94 vs 0.86) (the cloth moves ~1 mm per step relative to the body against 1.5 mm of
clearance). What it buys: recall on fast vertices diving from beyond the threshold
(tests/test_collision_recall.py: 100 % against the paper rule's 98.2 %).

The functions here are numpy and are the specification of the C kernels the detector runs
(measure.c: cluster motion and boxes in one call, ``cluster_state``; the pairs, the forced pairs
and ``RelativeMeasure``'s update in one, ``pair_step``, which the detector calls with a
``RelativeMeasure``'s state; ``RelativeMeasure.step`` calls the measure's C itself).
Cluster counts are ~30-1000, pairs a few hundred.
Units: metres.
"""
from __future__ import annotations

import numpy as np

from .. import _collide

__all__ = [
    "cluster_motion",
    "cluster_boxes",
    "box_pairs",
    "pair_keys",
    "RelativeMeasure",
    "AbsoluteMeasure",
    "TripMeasure",
    "cluster_fit",
    "pair_motion",
    "MEASURES",
    "TRIP_RULES",
]

MEASURES = ("relative", "absolute", "full")
# how the relative measure trips full detection: 'bound' (the trip rule, default), 'paper' (eqs. 1-4
# against the threshold)
TRIP_RULES = ("bound", "paper")


def cluster_motion(clustering, displacement):
    """Per cluster: dis_avg (K,3) mean displacement and dis_dev (K,) standard deviation of the
    vertex displacements around that mean (root mean square of |d - dis_avg|), metres."""
    k = clustering.n_clusters
    if k == 0:
        return np.zeros((0, 3)), np.zeros(0)
    d = displacement[clustering.order]
    both = np.empty((d.shape[0], 4))
    both[:, :3] = d
    both[:, 3] = np.einsum("ij,ij->i", d, d)
    nonempty = clustering.sizes > 0
    sums = np.zeros((k, 4))
    sums[nonempty] = np.add.reduceat(both, clustering.starts[nonempty], axis=0)
    count = np.maximum(clustering.sizes, 1)[:, None]
    avg = sums[:, :3] / count
    var = sums[:, 3] / count[:, 0] - np.einsum("ij,ij->i", avg, avg)
    return avg, np.sqrt(np.maximum(var, 0.0))


def cluster_boxes(clustering, positions, inflate):
    """AABBs (lo, hi) (K,3) of each cluster's vertices and triangles, grown by ``inflate``."""
    k = clustering.n_clusters
    p = positions[clustering.box_index]
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    if p.shape[0]:
        sizes = np.diff(np.concatenate([clustering.box_starts, [p.shape[0]]]))
        ne = sizes > 0
        lo[ne] = np.minimum.reduceat(p, clustering.box_starts[ne], axis=0)
        hi[ne] = np.maximum.reduceat(p, clustering.box_starts[ne], axis=0)
    return lo - inflate, hi + inflate


def box_pairs(lo_a, hi_a, lo_b, hi_b, self_pairs=False):
    """Index pairs (i, j) of overlapping boxes; with ``self_pairs`` only i <= j (a == b)."""
    overlap = np.all((lo_a[:, None, :] <= hi_b[None, :, :]) & (lo_b[None, :, :] <= hi_a[:, None, :]), axis=2)
    if self_pairs:
        overlap = np.triu(overlap)
    i, j = np.nonzero(overlap)
    return i.astype(np.int64), j.astype(np.int64)


def _kept_pairs(keys, a_clusters, b_clusters):
    """Mask of the pair keys involving none of these clusters (a side, b side)."""
    drop = np.zeros(keys.size, bool)
    if a_clusters is not None and len(a_clusters):
        drop |= np.isin(keys >> 32, a_clusters)
    if b_clusters is not None and len(b_clusters):
        drop |= np.isin(keys & 0xFFFFFFFF, b_clusters)
    return ~drop


def pair_keys(i, j):
    return (np.asarray(i, np.int64) << 32) | np.asarray(j, np.int64)


class RelativeMeasure:
    """Accumulated relative displacement of the close pairs of one object pair (eqs. 1-4).

    ``lookahead`` (steps, 0 = off): batching, see the module docs."""

    def __init__(self, threshold, lookahead=0.0):
        self.threshold = float(threshold)
        self.lookahead = float(lookahead)
        self.keys = np.zeros(0, np.int64)
        self.rel_avg = np.zeros((0, 3))
        self.rel_dev = np.zeros(0)

    def step(self, i, j, avg_a, dev_a, avg_b, dev_b, force=None):
        """Update with this step's close pairs (i in object a, j in object b); returns a bool
        mask of the pairs that need full detection now (their measure is then reset).

        One C pass (``_collide.relative_measure``) merges the stored, sorted pair keys with this
        step's pairs; ``step_reference`` is the numpy specification."""
        i = np.ascontiguousarray(i, np.int64)
        j = np.ascontiguousarray(j, np.int64)
        p = i.shape[0]
        keys = np.empty(p, np.int64)
        rel_avg = np.empty((p, 3))
        rel_dev = np.empty(p)
        amplitude = np.empty(p)
        full = np.empty(p, bool)
        _collide.relative_measure(
            self.keys, self.rel_avg, self.rel_dev, i, j,
            np.ascontiguousarray(avg_a, np.float64), np.ascontiguousarray(dev_a, np.float64),
            np.ascontiguousarray(avg_b, np.float64), np.ascontiguousarray(dev_b, np.float64),
            None if force is None else np.ascontiguousarray(force, bool), self.threshold,
            keys, rel_avg, rel_dev, amplitude, full, self.lookahead,
        )
        self.keys, self.rel_avg, self.rel_dev = keys, rel_avg, rel_dev
        self.amplitude = amplitude
        return full

    def step_reference(self, i, j, avg_a, dev_a, avg_b, dev_b, force=None):
        """The numpy specification of ``step`` (same state, same result)."""
        keys = pair_keys(i, j)
        rel_avg = np.zeros((keys.size, 3))
        rel_dev = np.zeros(keys.size)
        if self.keys.size and keys.size:
            pos = np.searchsorted(self.keys, keys)
            pos = np.minimum(pos, self.keys.size - 1)
            known = self.keys[pos] == keys
            rel_avg[known] = self.rel_avg[pos[known]]
            rel_dev[known] = self.rel_dev[pos[known]]
        rel_avg += avg_a[i] - avg_b[j]
        rel_dev += dev_a[i] + dev_b[j]
        amplitude = np.sqrt(np.einsum("ij,ij->i", rel_avg, rel_avg)) + rel_dev
        full = amplitude > self.threshold
        if force is not None:
            full |= force
        if full.any() and self.lookahead > 0:
            rate = np.linalg.norm(avg_a[i] - avg_b[j], axis=1) + dev_a[i] + dev_b[j]
            full |= amplitude + self.lookahead * rate > self.threshold
        rel_avg[full] = 0.0
        rel_dev[full] = 0.0
        order = np.argsort(keys)
        self.keys, self.rel_avg, self.rel_dev = keys[order], rel_avg[order], rel_dev[order]
        self.amplitude = amplitude
        return full

    def forget(self, a_clusters=None, b_clusters=None):
        """Drop the history of pairs involving these clusters (they changed by tearing)."""
        if self.keys.size == 0:
            return
        keep = _kept_pairs(self.keys, a_clusters, b_clusters)
        self.keys, self.rel_avg, self.rel_dev = self.keys[keep], self.rel_avg[keep], self.rel_dev[keep]


class AbsoluteMeasure:
    """Accumulated absolute displacement of every cluster of one object, with no pairing.

    ``lookahead`` (steps, 0 = off): batching, see the module docs."""

    def __init__(self, threshold, lookahead=0.0):
        self.threshold = float(threshold)
        self.lookahead = float(lookahead)
        self.acc_avg = np.zeros((0, 3))
        self.acc_dev = np.zeros(0)

    def accumulate(self, avg, dev):
        """Add this step's motion; returns the bool mask (K,) of clusters due for full detection
        (amplitude over the threshold); their accumulators reset."""
        k = avg.shape[0]
        if self.acc_avg.shape[0] != k:
            grown_avg = np.zeros((k, 3))
            grown_dev = np.zeros(k)
            m = min(k, self.acc_avg.shape[0])
            grown_avg[:m] = self.acc_avg[:m]
            grown_dev[:m] = self.acc_dev[:m]
            self.acc_avg, self.acc_dev = grown_avg, grown_dev
        self.acc_avg += avg
        self.acc_dev += dev
        amplitude = np.sqrt(np.einsum("ij,ij->i", self.acc_avg, self.acc_avg)) + self.acc_dev
        due = amplitude > self.threshold
        if self.lookahead > 0 and due.any():
            rate = np.sqrt(np.einsum("ij,ij->i", avg, avg)) + dev
            due |= amplitude + self.lookahead * rate > self.threshold
        self.acc_avg[due] = 0.0
        self.acc_dev[due] = 0.0
        return due

    def forget(self, clusters):
        """Make these clusters due at the next step (their geometry changed by tearing)."""
        clusters = np.asarray(clusters, np.int64)
        clusters = clusters[clusters < self.acc_dev.shape[0]]
        self.acc_dev[clusters] = np.inf


def cluster_fit(clustering, positions, previous, reach):
    """numpy specification of ``_collide.cluster_fit``: (K, 17) rows c[3], t[3], L[9] (row-major), e,
    |L|_F of the affine fit of each cluster's displacement (L = 0 when that bounds tighter)."""
    k = clustering.n_clusters
    out = np.zeros((k, 17))
    for c in range(k):
        idx = clustering.order[clustering.ptr[c]:clustering.ptr[c + 1]]
        p, d = previous[idx], positions[idx] - previous[idx]
        cen = p.mean(axis=0) if idx.size else np.zeros(3)
        t = d.mean(axis=0) if idx.size else np.zeros(3)
        q, dd = p - cen, d - t
        C = q.T @ q
        C += (1e-3 * np.trace(C) / 3.0 + 1e-300) * np.eye(3)
        S = dd.T @ q
        L = S @ np.linalg.inv(C)
        ln = float(np.linalg.norm(L))
        res = lambda LL: float(np.linalg.norm(d - t - q @ LL.T, axis=1).max(initial=0.0))  # noqa: E731
        e, e0 = res(L), res(np.zeros((3, 3)))
        if not e + ln * reach < e0:
            L, e, ln = np.zeros((3, 3)), e0, 0.0
        out[c, :3], out[c, 3:6], out[c, 6:15], out[c, 15], out[c, 16] = cen, t, L.reshape(-1), e, ln
    return out


def pair_motion(i, j, a, b, reach):
    """numpy specification of ``_collide.pair_motion``; a, b = (clustering, positions, previous, fit)."""
    out = np.empty(len(i))

    def one_way(side, c, fit_row):
        cl, x, prev = side[:3]
        idx = cl.order[cl.ptr[c]:cl.ptr[c + 1]]
        q = prev[idx] - fit_row[:3]
        r = x[idx] - prev[idx] - fit_row[3:6] - q @ fit_row[6:15].reshape(3, 3).T
        return float(np.linalg.norm(r, axis=1).max(initial=0.0)) + fit_row[15] + fit_row[16] * reach

    for p, (ii, jj) in enumerate(zip(i, j)):
        out[p] = min(one_way(a, ii, b[3][jj]), one_way(b, jj, a[3][ii]))
    return np.where(np.isnan(out), np.inf, out)


class TripMeasure:
    """The trip rule (module docs) for the close pairs of one object pair: per pair the clearance
    spent since its last full detection. ``budget`` = track_range - thickness (m)."""

    def __init__(self, budget, thickness, inflate, lookahead=0.0):
        self.budget = float(budget)
        self.thickness = float(thickness)
        self.inflate = float(inflate)
        self.lookahead = float(lookahead)
        self.keys = np.zeros(0, np.int64)
        self.used = np.zeros(0)
        self.amplitude = np.zeros(0)

    def step(self, i, j, bound, lo_a, hi_a, lo_b, hi_b, force=None):
        """This step's close pairs (row-major, from box_pairs) and their motion bounds; returns the
        bool mask of the pairs that need full detection now (their spent clearance resets)."""
        p = i.shape[0]
        keys = np.empty(p, np.int64)
        used = np.empty(p)
        amplitude = np.empty(p)
        full = np.empty(p, bool)
        _collide.trip_measure(
            old_keys=self.keys, old_used=self.used, i=i, j=j, bound=bound, lo_a=lo_a, hi_a=hi_a, lo_b=lo_b,
            hi_b=hi_b, inflate=self.inflate, budget=self.budget, thickness=self.thickness,
            force=None if force is None else np.ascontiguousarray(force, bool), lookahead=self.lookahead,
            keys=keys, used=used, amplitude=amplitude, full=full,
        )
        self.keys, self.used, self.amplitude = keys, used, amplitude
        return full

    def step_reference(self, i, j, bound, lo_a, hi_a, lo_b, hi_b, force=None):
        """The numpy specification of ``step`` (same state, same result)."""
        keys = pair_keys(i, j)
        g = np.maximum(lo_b[j] - hi_a[i], lo_a[i] - hi_b[j]) + 2.0 * self.inflate
        gap = np.sqrt((np.where(g > 0, g, 0.0) ** 2).sum(axis=1))
        fresh = np.maximum(self.budget - (gap - self.thickness), 0.0)
        used = fresh.copy()
        if self.keys.size and keys.size:
            pos = np.minimum(np.searchsorted(self.keys, keys), self.keys.size - 1)
            known = self.keys[pos] == keys
            used[known] = np.minimum(self.used[pos[known]] + bound[known], fresh[known])
        used = np.where(np.isnan(used), np.inf, used)
        full = used > self.budget
        if force is not None:
            full |= force
        if full.any() and self.lookahead > 0:
            full |= used + self.lookahead * bound > self.budget
        self.amplitude = used.copy()
        used[full] = 0.0
        self.keys, self.used = keys, used
        return full

    def forget(self, a_clusters=None, b_clusters=None):
        """Drop the history of pairs involving these clusters (they changed by tearing): such a pair
        starts again from what its boxes prove."""
        if self.keys.size == 0:
            return
        keep = _kept_pairs(self.keys, a_clusters, b_clusters)
        self.keys, self.used = self.keys[keep], self.used[keep]
