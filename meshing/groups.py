"""Physical-group ids of the scene mesh, the one place they are defined.

Volumes: ``active`` (the electroded stack), ``passive`` (the constraining layer),
``coin``. Facets: ``clamp`` (x = 0 face of the DEA), ``electrode_top`` and
``electrode_bottom`` (faces of the active stack), ``dea_contact`` (the DEA's
underside), ``coin_top`` and ``coin_bottom``, ``symmetry`` (the mid-plane z = 0 of a half model).
"""

ACTIVE = 1
PASSIVE = 2
COIN = 3

CLAMP = 11
ELECTRODE_TOP = 12
ELECTRODE_BOTTOM = 13
DEA_CONTACT = 14
COIN_TOP = 15
COIN_BOTTOM = 16
SYMMETRY = 17

VOLUMES = {"active": ACTIVE, "passive": PASSIVE, "coin": COIN}
FACETS = {"clamp": CLAMP, "electrode_top": ELECTRODE_TOP, "electrode_bottom": ELECTRODE_BOTTOM,
          "dea_contact": DEA_CONTACT, "coin_top": COIN_TOP, "coin_bottom": COIN_BOTTOM,
          "symmetry": SYMMETRY}
NAMES = {**{v: k for k, v in VOLUMES.items()}, **{v: k for k, v in FACETS.items()}}
DEA_VOLUMES = ("active", "passive")
