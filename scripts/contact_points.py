"""What the resolved tip-coin patch does, point by point, under the 0 -> 400 V ramp.

A diagnostic for the surrogate's d (docs/surrogate.md, "Why the fit fails there"): it runs one
setup's ramp at a fidelity of ``coin_pull`` and records, at every step, the current position
of each quadrature point of the DEA-coin contact integral and its penetration (the normal
traction is k_n times it). At a few voltages it prints:

* ``pts vx``: the penetration-weighted mean x velocity of the touching points (mm/s),
  against the coin's ``u``;
* ``|vz|``: their mean sideways speed (mm/s; the patch spreads over the coin's rim);
* ``r``: |Fx| / (mu_t Fy) of the FEM;
* ``rim``: the share of touching points on the rim's fillet, where the normal has an x part;
* ``Fx_n/Fy``: that normal's share of Fx, per Fy (equal quadrature weights: a rough figure).

::

    .venv/bin/python scripts/contact_points.py C5 [--fidelity resolved] [--save probe_C5.npz]

About 5 minutes per setup on one core at ``resolved``. Not part of any make target.
"""
from __future__ import annotations

import argparse

import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("setup")
    p.add_argument("--fidelity", default="")
    p.add_argument("--mesh-dir", default=None, help="default /tmp/contact_points_<setup>")
    p.add_argument("--save", default=None, help="also save the per-point record (.npz)")
    p.add_argument("--voltages", default="260,300,340,370,390")
    args = p.parse_args(argv)

    from deapull import scene as scenes
    from deapull.fem_solver import contact
    from deapull.fem_solver.simulation import Simulation
    from deapull.fem_solver.stepping import as_arrays

    sc = scenes.load("coin_pull", setup=args.setup, overrides=scenes.fidelity_overrides("coin_pull", args.fidelity))
    sim = Simulation.from_scene(sc, mesh_dir=args.mesh_dir or f"/tmp/contact_points_{args.setup}")
    problem = sim.problem()
    points, depths, coin_x = [], [], []

    def on_step(i, t):
        x, depth = problem.contact_points()
        points.append(x.copy())
        depths.append(depth.copy())
        coin_x.append(float(problem.X.value))

    records = sim.stepper(problem, progress=False, on_step=on_step).run()
    a = as_arrays(records)
    P, D, XC = np.stack(points), np.stack(depths), np.array(coin_x)
    if args.save:
        np.savez(args.save, P=P, D=D, XC=XC, **a)
    lay = sim.layout
    R, top, er, mu_t = lay.obstacle_radius_m, lay.obstacle_top_y_m, sc.coin.edge_radius_m, sc.coin.mu_t
    print(f"{args.setup}: mu_t {mu_t}, mu_b {sc.coin.mu_b}, {P.shape[1]} contact points, {len(a['t'])} steps")
    print("    V   n  pts vx  coin u    |vz|      r    rim  Fx_n/Fy")
    for Vq in (float(v) for v in args.voltages.split(",")):
        i = int(np.argmin(abs(a["V"] - Vq)))
        if i == 0:
            continue
        on = D[i] > 0
        w, x = D[i][on], P[i][on]
        v = (P[i] - P[i - 1])[on] / (a["t"][i] - a["t"][i - 1])
        rx, rz = x[:, 0] - lay.obstacle_center_x_m - XC[i], x[:, 2]
        rho = np.hypot(rx, rz)
        n_r, n_y, rim = contact.rounded_cylinder_normal(rho, x[:, 1], top, R, er, sc.coin.edge_shape)
        n_x = n_r * rx / rho
        print(f"{a['V'][i]:5.0f} {on.sum():3d} {1e3 * np.sum(w * v[:, 0]) / w.sum():7.3f} {1e3 * a['u'][i]:7.3f} "
              f"{1e3 * np.mean(abs(v[:, 2])):7.3f} {abs(a['Fx'][i]) / (mu_t * abs(a['Fy'][i])):6.3f} "
              f"{rim.mean():6.2f} {-np.sum(w * n_x) / np.sum(w * n_y):8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
