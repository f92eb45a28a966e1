#!/usr/bin/env python3
"""The time-optimal motion along planned paths, by TOPP-RA (the `toppra` package on PyPI).

Reads the paths `cargo run --release --example time_optimal` exports (one JSON file a program:
the planned path sampled densely, each sample's joints and world axes with limits through the
machine's inverse kinematics, the program line and the programmed feed there, cut into pieces
where the tool stops), and writes beside each file `NAME.toppra.json`: the time-optimal motion's
duration (s) and its time per program line, under

- every joint's (and limited world axis') speed and acceleration limits, exactly as given;
- the programmed feed as a limit on the path speed (rapids: the joints' limits alone);
- rest at both ends of every piece.

The path between samples is a cubic spline through them (toppra's SplineInterpolator); the
samples are 0.02 mm apart at most and at least 16 an element of the path, so a blend of a few
hundredths of a millimetre keeps its curvature. A joint whose every sample mirrors another's
(the O-X glide's two sliders at constant z: s1 = x + c, s2 = −x + c) is redundant, and toppra's
solver can fail on such a pair: it is dropped.

Usage: tools/toppra_bench.py FILE.json...   (run it with the interpreter of the virtual
environment toppra is installed in: the example makes one under target/ and says how)
"""

import json
import math
import sys

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint

# A bound toppra can take where there is none (a virtual coordinate's acceleration, a rapid's
# path speed): far above any machine's, not so far that the solver loses precision.
NONE = 1e4


class CleanPath(toppra.SplineInterpolator):
    """A cubic spline whose derivatives below 1e-12 are zero: a coordinate that stands still
    over part of a piece gets derivatives of 1e-40 there from the spline's arithmetic, and the
    solver divides by them."""

    def __call__(self, path_positions, order=0):
        out = np.array(super().__call__(path_positions, order))
        if order > 0:
            out[np.abs(out) < 1e-12] = 0.0
        return out


class Acceleration(toppra.constraint.JointAccelerationConstraint):
    """Every coordinate's acceleration limit; where at a grid point one coordinate's
    derivatives repeat or mirror another's with the same limit (the O-X glide's two sliders
    wherever z stands still), its rows are left out there: they say nothing more, and toppra's
    solver fails on such a pair."""

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        ps = np.array(path(gridpoints, order=1)).reshape((-1, path.dof))
        pss = np.array(path(gridpoints, order=2)).reshape((-1, path.dof))
        dof = path.dof
        for j in range(dof):
            for k in range(j + 1, dof):
                if not np.array_equal(self.alim[j], self.alim[k]):
                    continue
                scale = np.maximum(np.abs(ps[:, j]) + np.abs(pss[:, j]), 1e-12)
                same = (np.abs(ps[:, j] - ps[:, k]) + np.abs(pss[:, j] - pss[:, k])) <= 1e-9 * scale
                mirror = (np.abs(ps[:, j] + ps[:, k]) + np.abs(pss[:, j] + pss[:, k])) <= 1e-9 * scale
                repeat = same | mirror
                ps[repeat, k] = 0.0
                pss[repeat, k] = 0.0
        F = np.vstack([np.eye(dof), -np.eye(dof)])
        g = np.concatenate([self.alim[:, 1], -self.alim[:, 0]])
        zeros = np.zeros_like(ps)
        if self.discretization_type == toppra.constraint.DiscretizationType.Collocation:
            return ps, pss, zeros, F, g, None, None
        return toppra.constraint.canlinear_colloc_to_interpolate(
            ps, pss, zeros, F, g, None, None, gridpoints, identical=True
        )


def redundant(qs, vlim, alim):
    """The columns of `qs` that mirror or repeat an earlier column with the same limits."""
    drop = set()
    n = qs.shape[1]
    for j in range(n):
        for k in range(j + 1, n):
            if k in drop or j in drop:
                continue
            if vlim[j] != vlim[k] or alim[j] != alim[k]:
                continue
            if np.ptp(qs[:, j] + qs[:, k]) < 1e-9 or np.ptp(qs[:, j] - qs[:, k]) < 1e-9:
                drop.add(k)
    return sorted(drop)


def piece_time(piece, vlim, alim):
    """The time-optimal duration of one piece (rest to rest) and the time per grid interval."""
    ss = np.array(piece["s"], dtype=float)
    qs = np.array(piece["q"], dtype=float)
    lines = np.array(piece["line"], dtype=int)
    feeds = np.array([NONE if f is None else f for f in piece["feed"]], dtype=float)
    # Strictly increasing path positions (element ends meet at one s).
    keep = np.concatenate(([True], np.diff(ss) > 1e-12))
    ss, qs, lines, feeds = ss[keep], qs[keep], lines[keep], feeds[keep]
    if len(ss) < 2 or ss[-1] - ss[0] <= 0.0:
        return 0.0, [], lines
    drop = redundant(qs, vlim, alim)
    cols = [c for c in range(qs.shape[1]) if c not in drop]
    qs = qs[:, cols]
    v = np.array([vlim[c] for c in cols] + [NONE])
    a = np.array([alim[c] for c in cols] + [NONE])
    # The virtual coordinate: the path position itself, whose speed is bounded by the feed.
    path = CleanPath(ss, np.column_stack([qs, ss]))
    # The feed of the sample at or before s (each sample carries its element's feed; a
    # junction takes the slower of the two, as the planner does).
    def vlim_at(s):
        i = int(np.clip(np.searchsorted(ss, s, side="right") - 1, 0, len(ss) - 1))
        f = feeds[i]
        if i + 1 < len(ss) and abs(ss[i + 1] - s) < 1e-12:
            f = min(f, feeds[i + 1])
        out = np.column_stack([-v, v])
        out[-1] = [-f, f]
        return out

    # The acceleration constraints hold at both ends of each grid interval (interpolation);
    # where toppra's solver meets a numerical failure with them (seen on a long raster on the O-X
    # glide), at each grid point (collocation: on a grid this fine, within 0.01 % of it).
    sd = None
    for scheme in (
        toppra.constraint.DiscretizationType.Interpolation,
        toppra.constraint.DiscretizationType.Collocation,
    ):
        constraints = [
            toppra.constraint.JointVelocityConstraintVarying(vlim_at),
            Acceleration(np.column_stack([-a, a]), discretization_scheme=scheme),
        ]
        algo = toppra.algorithm.TOPPRA(constraints, path, gridpoints=ss, solver_wrapper="seidel")
        _, sd, _, _ = algo.compute_parameterization(0.0, 0.0, return_data=True)
        if sd is not None:
            break
        print(f"  a piece of {ss[-1] - ss[0]:.3f} mm: {scheme.name} failed", file=sys.stderr)
    if sd is None:
        raise RuntimeError("toppra found no parameterization")
    # Constant acceleration between grid points: Δt = 2 Δs / (ṡ₀ + ṡ₁).
    dts = []
    for i in range(len(ss) - 1):
        speed = sd[i] + sd[i + 1]
        dts.append(2.0 * (ss[i + 1] - ss[i]) / speed if speed > 0.0 else math.inf)
    return float(sum(dts)), dts, lines


def bench(file):
    with open(file) as f:
        data = json.load(f)
    vlim, alim = data["speed"], data["accel"]
    total = 0.0
    per_line = {}
    for piece in data["pieces"]:
        t, dts, lines = piece_time(piece, vlim, alim)
        total += t
        # Each interval belongs to the line of its start.
        for dt, line in zip(dts, lines):
            per_line[int(line)] = per_line.get(int(line), 0.0) + dt
    out = {"time_s": total, "per_line": {str(k): v for k, v in sorted(per_line.items())}}
    result = file[: -len(".json")] + ".toppra.json"
    with open(result, "w") as f:
        json.dump(out, f)
    print(f"{file}: {total:.4f} s")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        print(__doc__)
        sys.exit(2)
    for name in sys.argv[1:]:
        bench(name)
