"""Could a tip patch that is a function of the voltage alone carry one coin's data to another coin?

A diagnostic for the surrogate's sets (docs/surrogate.md, "The patch probe"). Every dataset
records, at each step, the contact patch's side of the friction (deapull/dataset.py): the
patch's speed ``patch_vx``, the x push of the normal traction ``patch_normal_x`` (N_x) and the
friction per unit mu_t that a coin moving at c x patch_vx would feel, ``patch_drag_*`` (D(c)),
for c in ``dataset.PATCH_SHARES``. A coin slides where the patch beats the ground and then moves
at the share c that balances it (quasi-static; the coin's inertia is ~1e-3 of the forces):

    N_x + mu_t D(c) = -mu_b (m_c g + Fy)      (the coin goes toward -x; D < 0 pulls it there),
    the coin sticks where N_x + mu_t D(0) > -mu_b (m_c g + Fy).

Fed a coin's own patch this reproduces the FEM's coin (the "self" columns). Fed the training
coin's patch, changing only phi (m_c, mu_t, mu_b), it is what any surrogate does whose m makes
the patch (its speed, pressing force and friction-speed curve) a function of V alone: the
best such a model can do on the paper's six sets {C_i -> C_i+2}. It prints the MAE of x(t) and
the travel error, in % of the test coin's travel. Needs a sweep that recorded the probe (made
since the twentieth session); runs in a second.

::

    .venv/bin/python scripts/patch_probe.py [--data data] [--plot docs/img/patch_probe.png]

``--plot`` draws the friction-speed curves D(c)/D(0) of the training and test coins of set 3
(C3, C5) at a few voltages.

Not part of any make target.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deapull import dataset

G = 9.81
SHARES = np.asarray(dataset.PATCH_SHARES)


def load(path: Path) -> dict:
    """The columns and the coin of one dataset, through the dataset contract."""
    run = dataset.read(path, ("t", "V", "x", "u", "Fy", "patch_vx", "patch_normal_x", *dataset.PATCH_DRAGS))
    d = dict(run.columns)
    d["drag"] = np.stack([d.pop(n) for n in dataset.PATCH_DRAGS], axis=1)
    d.update(m=run.number("coin_mass_kg"), mu_t=run.number("coin_mu_t"), mu_b=run.number("coin_mu_b"))
    return d


def share(normal_x: float, drag: np.ndarray, mu_t: float, ground: float) -> float:
    """The coin's speed over the patch's, c, where N_x + mu_t D(c) = -ground (0 where it sticks);
    D between the probed shares linearly, and past the last one along its last slope."""
    f = normal_x + mu_t * drag
    if f[0] >= -ground:
        return 0.0
    if f[-1] <= -ground:                  # faster than the last probed share
        slope = (f[-1] - f[-2]) / (SHARES[-1] - SHARES[-2])
        return float(SHARES[-1] + (-ground - f[-1]) / slope) if slope > 0 else float(SHARES[-1])
    return float(np.interp(-ground, f, SHARES))


def predict(patch: dict, coin: dict) -> np.ndarray:
    """x(t) (m, toward -x) of ``coin``'s mass and frictions under ``patch``'s patch, at its times."""
    t, u = patch["t"], np.zeros(len(patch["t"]))
    for i in range(1, len(t)):
        fy = patch["Fy"][i]
        if fy <= 0 or patch["patch_vx"][i] == 0:
            continue
        c = share(patch["patch_normal_x"][i], patch["drag"][i], coin["mu_t"], coin["mu_b"] * (coin["m"] * G + fy))
        u[i] = c * patch["patch_vx"][i]
    return np.concatenate([[0.0], np.cumsum(u[1:] * np.diff(t))])


def errors(patch: dict, coin: dict) -> tuple[float, float]:
    """(MAE of x, travel error) of ``predict``, % of ``coin``'s travel."""
    x = predict(patch, coin)
    truth = np.interp(patch["t"], coin["t"], coin["x"])
    travel = np.abs(coin["x"]).max()
    return 100 * np.mean(np.abs(x - truth)) / travel, 100 * (abs(x[-1]) - abs(truth[-1])) / travel


def plot(runs: dict, path: Path, of_top=(0.75, 0.85, 0.925, 0.975)) -> Path:
    """D(c)/D(0) of C3's and C5's patches at the voltages ``of_top`` × the ramp's top (on the way
    up: 300, 340, 370 and 390 V on the 400 V ramp), with each coin's own c."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for k, share_of_top in enumerate(of_top):
        for name, style in (("C3", "-"), ("C5", "--")):
            d = runs[int(name[1])]
            up = np.arange(int(np.argmax(d["V"])) + 1)
            v = share_of_top * d["V"].max()
            i = up[int(np.argmin(np.abs(d["V"][up] - v)))]
            curve = d["drag"][i] / d["drag"][i, 0]
            colour = f"C{k}"
            ax.plot(SHARES, curve, style, color=colour, marker="o", ms=3, label=f"{name}, {d['V'][i]:.0f} V")
            c = d["u"][i] / d["patch_vx"][i]
            ax.plot([c], [np.interp(c, SHARES, curve)], "x" if name == "C3" else "s", color=colour, ms=7, mfc="none")
    ax.set_xlabel("coin speed / patch speed, c")
    ax.set_ylabel("drag D(c) / D(0)")
    ax.set_title("the patch's friction-speed curve under C3 (solid) and C5 (dashed);\n"
                 "markers: where each coin moved", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="data", type=Path, help="folder with C1.nc .. C8.nc (make sweep)")
    p.add_argument("--plot", type=Path, help="also draw set 3's curves (C3, C5) into this PNG")
    args = p.parse_args(argv)
    missing = [f"C{i}.nc" for i in range(1, 9) if not (args.data / f"C{i}.nc").is_file()]
    if missing:
        p.error(f"--data {str(args.data)!r} lacks {', '.join(missing)} (make sweep)")
    runs = {i: load(args.data / f"C{i}.nc") for i in range(1, 9)}
    print("set (train -> test)   training coin's patch: MAE x, travel    test coin's own patch: MAE x, travel"
          "   [% of the test coin's travel]")
    for i in range(1, 7):
        a, b = errors(runs[i], runs[i + 2]), errors(runs[i + 2], runs[i + 2])
        print(f"{i} (C{i} -> C{i + 2})          {a[0]:6.2f}  {a[1]:+6.1f}                        "
              f"{b[0]:6.2f}  {b[1]:+6.1f}")
    if args.plot:
        print(f"wrote {plot(runs, args.plot)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
