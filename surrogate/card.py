"""A model card: what a trained surrogate was trained on, how well it did, and where it is known to fail.

:func:`build` makes the card from a training summary (:meth:`surrogate.train.TrainResult.summary`);
:mod:`surrogate.store` writes it into ``model.json`` as ``card``:

* ``fidelity`` and ``fidelity_id`` — the FEM fidelity of the training data ("as written": the
  scene file as written, the data fidelity; a ``[fidelities.NAME]``; "custom": other overrides)
  and the fingerprint of its mesh, solver, contact and time sections
  (:func:`deapull.scene.fidelity_of_resolved`);
* ``datasets`` — the SHA-256 of every training and validation file, by setup;
* ``training_coins``, ``validation_coins`` and ``coins`` — the setups and the box of their
  (m_c, μ_b, μ_t);
* ``metrics`` — the kept restart's validation rollout error and, when the experiments add it,
  the test setup's errors;
* ``known_limits`` — the inputs the training data never showed, in words.

:func:`check` compares a dataset with a card: another fidelity, a changed file of a setup the
model was trained on, or a coin outside the training box each give a message (``deapull
evaluate`` prints them as warnings).
"""
from __future__ import annotations

import math

FIDELITY_NAMES = {"": "as written", None: "custom"}
COIN_FIELDS = (("coin_mass_kg", "m_c", 1e3, "g"), ("mu_b", "μ_b", 1.0, ""), ("mu_t", "μ_t", 1.0, ""))


def fidelity_label(name: str | None) -> str:
    """A dataset's fidelity name as the card writes it."""
    return FIDELITY_NAMES.get(name, name)


def build(training: dict, test: dict | None = None) -> dict:
    """The card of a model from its training summary (``setups``, ``val_x_error_pct``) and, optionally,
    the metrics of its test rollout (:func:`surrogate.evaluate.evaluate`)."""
    setups = training.get("setups", {})
    train = [n for n, s in setups.items() if "train" in s["role"]]
    val = [n for n, s in setups.items() if "val" in s["role"]]
    fidelities = {fidelity_label(s.get("fidelity")) for s in setups.values()}
    ids = {s.get("fidelity_id", "") for s in setups.values()}
    coins = {}
    for key, _, _, _ in COIN_FIELDS:
        values = [s[key] for n, s in setups.items() if n in train and s.get(key) is not None
                  and math.isfinite(s[key])]
        coins[key] = [min(values), max(values)] if values else None
    metrics = {"validation_x_error_pct_travel": training.get("val_x_error_pct")}
    if test:
        metrics["test"] = {k: test.get(k) for k in ("setup", "mae_x_m", "mae_Fx_N", "mae_Fy_N", "x_error_pct_travel",
                                                    "max_abs_x_error_m", "diverged")}
    return {"fidelity": fidelities.pop() if len(fidelities) == 1 else "mixed",
            "fidelity_id": ids.pop() if len(ids) == 1 else "mixed",
            "datasets": {n: s.get("sha256", "") for n, s in setups.items()},
            "training_coins": train, "validation_coins": val, "coins": coins,
            "metrics": metrics, "known_limits": known_limits(setups, train, coins)}


def known_limits(setups: dict, train: list[str], coins: dict) -> list[str]:
    """The inputs the training runs never showed, in words."""
    runs = [setups[n] for n in train]
    out = []
    v_lo, v_hi = min(r.get("v_min_V", 0.0) for r in runs), max(r.get("v_max_V", 0.0) for r in runs)
    out.append(f"voltages outside [{v_lo:g}, {v_hi:g}] V (the training runs' span; rollouts warn beyond 5 % of it)")
    if not any(r.get("v_falls") for r in runs):
        out.append("a falling voltage (a release or a triangle): every training run's voltage only rises")
    box = [f"{label} in [{lo * scale:.4g}, {hi * scale:.4g}]{(' ' + unit) if unit else ''}"
           for key, label, scale, unit in COIN_FIELDS if (span := coins.get(key)) for lo, hi in [span]]
    if box:
        out.append(f"coins outside {', '.join(box)} (the training coins {','.join(train)}): the coin's law d "
                   "extrapolates there, the material network m does not see the coin")
    return out


def check(card: dict, data) -> list[str]:
    """Messages on how ``data`` (a :class:`~deapull.surrogate.data.SetupData`) differs from what the
    model with ``card`` was trained on; empty when it matches."""
    if not card:
        return [f"the model has no card (saved before model cards): {data.name} cannot be checked against its "
                "training data"]
    out = []
    if card.get("fidelity_id") and data.fidelity_id != card["fidelity_id"]:
        out.append(f"{data.path}: made at fidelity {fidelity_label(data.fidelity)!r} ({data.fidelity_id or 'unknown'}), "
                   f"the model was trained at {card.get('fidelity')!r} ({card['fidelity_id']})")
    trained = card.get("datasets", {}).get(data.name)
    if trained and data.sha256 != trained:
        out.append(f"{data.path}: not the file the model was trained on for {data.name} (SHA-256 "
                   f"{data.sha256[:12]}, trained on {trained[:12]})")
    values = {"coin_mass_kg": data.mass_kg, "mu_b": data.mu_b, "mu_t": data.mu_t}
    for key, label, scale, unit in COIN_FIELDS:
        span = (card.get("coins") or {}).get(key)
        if span and math.isfinite(values[key]) and not span[0] * (1 - 1e-9) <= values[key] <= span[1] * (1 + 1e-9):
            out.append(f"{data.name}: coin {label} = {values[key] * scale:.4g}{(' ' + unit) if unit else ''} is outside "
                       f"the training coins' [{span[0] * scale:.4g}, {span[1] * scale:.4g}]: the prediction "
                       "extrapolates")
    return out
