"""Could one effective sideways slip w_z(V) carry the resolved patch into the surrogate's d?

A diagnostic for the surrogate's d (docs/surrogate.md, "An effective sideways slip"): on the
resolved patch the coin slips under the tip, and |Fx| / (mu_t Fy) stays below 1 while it does.
A point contact whose slip has a sideways part w_z explains that ratio by its direction:

    |Fx| = mu_t Fy (w - u) / sqrt((w - u)^2 + w_z^2),    w = the tip's x speed (tip_ux),

and a sliding coin carries |Fx| = mu_b (m_c g + Fy). This script reads w_z(V) off the training
coin's dataset (its tip speed, u, Fx and Fy), then predicts the test coin of each of the
paper's six sets {C_i -> C_i+2} from the training coin's tip speed and Fy, changing only phi
(m_c, mu_b, mu_t), as a d fed by a coin-independent m would. Beside it, the same prediction
with a tip that carries the coin (u = the training coin's u wherever Coulomb lets the coin
slide), the structure of f-coulomb's d. It prints the MAE of x(t) and the travel error, both
in % of the test coin's travel. Needs the sweep's datasets; runs in a second.

::

    .venv/bin/python scripts/effective_slip.py [--data data]

Not part of any make target: nothing of it is in the surrogate (docs/surrogate.md says why).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import h5py
import numpy as np

G = 9.81


def load(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        d = {k: np.asarray(f[k][:], dtype=float) for k in ("t", "V", "x", "u", "Fx", "Fy", "tip_ux")}
        d.update(m=float(f.attrs["coin_mass_kg"][0]), mu_t=float(f.attrs["coin_mu_t"][0]),
                 mu_b=float(f.attrs["coin_mu_b"][0]))
    d["w"] = np.gradient(-d["tip_ux"], d["t"])     # the tip's speed toward -x, where the coin goes
    return d


def sideways_slip(train: dict):
    """w_z(V) from the training coin where it slides: w_z = (w - u) sqrt(1 - r^2) / r."""
    u = -train["u"]
    r = np.clip(np.abs(train["Fx"]) / (train["mu_t"] * np.abs(train["Fy"])), 1e-6, 0.999)
    wz = (train["w"] - u) * np.sqrt(1 - r * r) / r
    ok = (u > 1e-5) & (train["w"] > 1e-5) & np.isfinite(wz)
    return lambda V: np.interp(V, train["V"][ok], wz[ok])


def predict(train: dict, test: dict, carried: bool) -> tuple[float, float]:
    """(MAE of x, travel error), % of the test coin's travel, from the training coin's m."""
    w, fy, t = train["w"], np.abs(train["Fy"]), train["t"]
    need = test["mu_b"] * (test["m"] * G + fy) / (test["mu_t"] * fy)     # |Fx| / (mu_t Fy) when sliding
    if carried:
        u = np.where(need < 1, -train["u"], 0.0)
    else:
        wz = sideways_slip(train)(train["V"])
        slides = (w > 0) & (need < 1) & (w / np.sqrt(w * w + wz * wz) > need)
        u = np.where(slides, np.clip(w - wz * need / np.sqrt(np.clip(1 - need * need, 1e-9, None)), 0, w), 0.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] + u[:-1]) * np.diff(t))])
    truth = np.interp(t, test["t"], -test["x"])
    travel = truth[-1]
    return 100 * np.mean(np.abs(x - truth)) / travel, 100 * (x[-1] - travel) / travel


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="data", type=Path, help="folder with C1.nc .. C8.nc (make sweep)")
    args = p.parse_args(argv)
    missing = [f"C{i}.nc" for i in range(1, 9) if not (args.data / f"C{i}.nc").is_file()]
    if missing:
        p.error(f"--data {str(args.data)!r} lacks {', '.join(missing)} (make sweep)")
    sets = {i: load(args.data / f"C{i}.nc") for i in range(1, 9)}
    print("set (train -> test)   sideways slip: MAE x, travel    carried (f-coulomb's d): MAE x, travel   [% of travel]")
    for i in range(1, 7):
        a = predict(sets[i], sets[i + 2], carried=False)
        b = predict(sets[i], sets[i + 2], carried=True)
        print(f"{i} (C{i} -> C{i + 2})          {a[0]:6.2f}  {a[1]:+6.1f}                     {b[0]:6.2f}  {b[1]:+6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
