"""Scene files: TOML → validated, frozen dataclasses.

(Longer than ~500 lines on purpose: the sections, their fields' ranges and docs, and the
validation that reads those ranges are one schema; it is also the README's key table.)

A scene says what the simulation contains. Every quantity is SI with its unit in
the key's name (``coin.density_kg_m3``, ``load.voltage_max_V``). Sections that a
scene does not have (``coin``, ``stop``, ``table``) are ``None`` and the solver assembles
nothing for them.

Validation happens here, before any meshing or solving: unknown or missing keys,
wrong types, NaN/inf, out-of-range values and unknown setups all raise
:class:`SceneError`, whose message names the key, the value and what is allowed.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import tomli_w

from deapull import protocol as protocols
from deapull.errors import InputError

SCENE_DIR = Path(__file__).parent / "scenes"


class SceneError(InputError):
    """Invalid scene input; the message names the key, the value and what is allowed."""


# --- field helpers -----------------------------------------------------------------

def _num(default, lo=None, hi=None, lo_open=True, hi_open=False, doc="", integer=False):
    """A numeric field with an allowed range; ``lo_open`` means strictly greater."""
    return field(default=default, metadata=dict(kind="int" if integer else "float", lo=lo, hi=hi,
                                                lo_open=lo_open, hi_open=hi_open, doc=doc))


def _pos(default, doc=""):
    return _num(default, lo=0.0, doc=doc)


def _nonneg(default, doc=""):
    return _num(default, lo=0.0, lo_open=False, doc=doc)


def _choice(default, choices, doc=""):
    return field(default=default, metadata=dict(kind="choice", choices=tuple(choices), doc=doc))


def _text(default, doc=""):
    return field(default=default, metadata=dict(kind="str", doc=doc))


def _floats(doc=""):
    return field(default=(), metadata=dict(kind="floats", doc=doc))


REQUIRED = object()

#: keys that a newer key replaced -> what to write instead
REPLACED = {
    "contact.penalty_scale": "give contact.penalty_N_m3, the normal penalty in N/m^3 (independent of the mesh "
                             "and the rule; the old k_n was penalty_scale * E / h_tip, 2.24e9 N/m^3 for 10 on the "
                             "shipped mesh)",
}


# --- sections ----------------------------------------------------------------------

@dataclass(frozen=True)
class SceneInfo:
    name: str = _text(REQUIRED, "scene name")
    description: str = _text(REQUIRED, "one-line description")
    default_setup: str = _text("", "setup used when --setup is not given (empty: none)")


@dataclass(frozen=True)
class DEA:
    length_m: float = _pos(0.040, "length along x, clamp at x = 0, free end at x = -length")
    width_m: float = _pos(0.020, "width along z")
    active_thickness_m: float = _pos(0.002, "thickness of the active stack (y)")
    passive_thickness_m: float = _pos(0.001, "thickness of the passive layer (y)")
    film_thickness_m: float = _pos(10e-6, "thickness of one dielectric film; field = V / film")
    youngs_modulus_Pa: float = _pos(0.56e6, "Young's modulus of both layers")
    poisson_ratio: float = _num(0.5, lo=-1.0, hi=0.5, doc="Poisson ratio, in (-1, 0.5]; 0.5 = incompressible")
    density_kg_m3: float = _pos(1100.0, "elastomer density")
    relative_permittivity: float = _num(4.7, lo=1.0, lo_open=False, doc="relative permittivity of the films")
    material: str = _choice("neo_hookean", ("neo_hookean", "gent"), "hyperelastic law")
    gent_locking_I1: float = _pos(100.0, "Gent J_m: I1 - 3 at locking (material = gent)")
    active_side: str = _choice("top", ("top", "bottom"), "which layer carries the electrodes")
    clamp_gap_m: float = _nonneg(0.0, "height of the clamped underside above the coin's / stop's top face; "
                                      "gravity sag closes it (pre-load)")
    free_edge_radius_m: float = _nonneg(0.0, "radius of the rounded edge where the free end face meets the underside "
                                             "(the edge that rides onto the coin's rim; 0: a sharp 90 degree edge, "
                                             "whose contact with the rim is singular)")


@dataclass(frozen=True)
class Coin:
    radius_m: float = _pos(0.005, "coin radius")
    height_m: float = _pos(0.00225, "coin height (y); the DEA rests on its top face")
    density_kg_m3: float = _pos(7700.0, "coin density; mass = mesh volume x density")
    edge_radius_m: float = _pos(0.0003, "fillet radius of the coin's top rim")
    edge_shape: str = _choice("circular", ("circular", "c2"), "profile of the rim: circular (a quarter circle: "
                              "its curvature jumps from 0 to 1/edge_radius_m where it meets the top face) or "
                              "c2 (a superellipse blend: curvature continuous, 0 at both tangencies)")
    mu_t: float = _nonneg(0.55, "Coulomb friction DEA-coin (top)")
    mu_b: float = _nonneg(0.20, "Coulomb friction coin-ground (bottom)")
    center_from_tip_m: float = _num(0.003, doc="x distance from the DEA's free end to the coin centre, "
                                               "toward the clamp (< radius_m: the tip rests on the top face)")


@dataclass(frozen=True)
class Stop:
    height_m: float = _pos(0.00225, "height of the fixed rigid stop's top face (y)")
    radius_m: float = _pos(0.005, "radius of the stop's disc footprint")
    center_from_tip_m: float = _num(0.003, doc="x distance from the free end to the stop centre")
    edge_radius_m: float = _pos(0.0003, "fillet radius of the stop's top rim")
    edge_shape: str = _choice("circular", ("circular", "c2"), "profile of the rim, as coin.edge_shape")
    mu_t: float = _nonneg(0.55, "Coulomb friction DEA-stop")


@dataclass(frozen=True)
class Table:
    """The fixed surface the DEA lies on (paper Sec. IV: "a unimorph DEA on the fixed surface"):
    the plane y = height_m, which the DEA's underside may touch where it drapes; the coin
    stands on the same plane (y = 0). Not the load protocol's ``table`` of (t, V) points."""
    height_m: float = _num(0.0, doc="y of the table's top face (the coin stands on y = 0)")
    mu_g: float = _nonneg(0.0, "Coulomb friction DEA-table")
    penalty_N_m3: float = _pos(1e11, "normal penalty of the DEA-table contact (N/m^3: pressure per metre "
                                     "of penetration)")
    quadrature_degree: int = _num(6, lo=0, integer=True, doc="quadrature degree of the DEA-table integrals "
                                                            "(Gauss-Lobatto points: they include the corners)")


@dataclass(frozen=True)
class Contact:
    penalty_N_m3: float = _pos(2.24e9, "normal penalty k_n of the DEA-obstacle contact: pressure per metre of "
                                       "penetration (N/m^3), independent of the mesh and the rule")
    slip_rate_regularisation_m_s: float = _pos(1e-5, "slip rate at which regularised Coulomb friction "
                                                      "reaches ~70 % of mu*p")
    quadrature_degree: int = _num(4, lo=0, integer=True, doc="quadrature degree of the contact and friction "
                                  "integrals on the DEA's underside (own measure, independent of "
                                  "solver.quadrature_degree)")
    min_active_points: int = _num(20, lo=0, lo_open=False, integer=True,
                                  doc="fewest quadrature points that should carry the DEA-obstacle contact; "
                                      "the solver warns on a step with fewer (0: never)")
    quadrature_rule: str = _choice("gauss", ("gauss", "gauss_lobatto"),
                                   "points of the contact integrals: gauss (interior points) or gauss_lobatto "
                                   "(includes the facet's edges and corners, where the patch ends)")
    reach_m: float = _nonneg(0.0, "the DEA-obstacle integral runs over the underside facets within this distance "
                                  "(along x, at rest) of the obstacle's footprint; a record where the DEA touches "
                                  "the obstacle outside them stops the run (0: the whole underside)")


@dataclass(frozen=True)
class Load:
    """The voltage protocol (:mod:`deapull.protocol`): each protocol takes only its own keys."""
    protocol: str = _choice("ramp", protocols.NAMES, "voltage protocol V(t) (deapull/protocol.py): "
                                                     + ", ".join(protocols.NAMES))
    voltage_max_V: float = _nonneg(400.0, "largest voltage: every protocol's V(t) lies in [0, voltage_max_V]")
    end_time_s: float = _pos(1.0, "end of the simulation")
    ramp_time_s: float = _pos(1.0, "ramp, release, triangle, ramp_hold_ramp: duration of the (first) ramp")
    hold_time_s: float = _nonneg(0.5, "ramp_hold_ramp: hold at voltage_max_V after the first ramp")
    voltage_end_V: float = _nonneg(0.0, "ramp_hold_ramp: voltage at the end of the second ramp (<= voltage_max_V)")
    ramp_down_time_s: float = _pos(0.5, "ramp_hold_ramp: duration of the second ramp")
    period_s: float = _pos(1.0, "sine: period of V_max (1 - cos(2 pi t / period)) / 2")
    table_t_s: tuple = _floats("table: times of the points (s), from 0, strictly increasing")
    table_V: tuple = _floats("table: voltages of the points (V), in [0, voltage_max_V]")
    table_csv: str = _text("", "table: CSV file of (t_s, V) rows instead of table_t_s/table_V (relative paths: "
                               "from the scene file's folder)")
    seed: int = _num(0, lo=0, lo_open=False, integer=True, doc="random: seed of the generator")
    rate_max_V_s: float = _num(1000.0, lo=protocols.RATE_RANGE[0], hi=protocols.RATE_RANGE[1], lo_open=False,
                               doc="random: bound of |dV/dt| (V/s)")
    segment_min_s: float = _pos(0.05, "random: shortest segment (s)")
    segment_max_s: float = _pos(0.2, "random: longest segment (s)")

    def keys(self) -> tuple[str, ...]:
        """The keys this protocol takes (the others are refused in a scene file)."""
        return protocols.COMMON + protocols.KEYS[self.protocol]


@dataclass(frozen=True)
class Time:
    dt_max_s: float = _pos(1.0 / 720.0, "largest step; 1 s gives >= 700 steps when <= 1/700")
    dt_min_s: float = _pos(1e-7, "smallest step before the solve is declared failed")
    dt_initial_s: float = _pos(1e-3, "first step")
    growth: float = _num(1.5, lo=1.0, lo_open=False, doc="step growth factor after an easy solve")
    cutback: float = _num(0.5, lo=0.0, hi=1.0, hi_open=True, doc="step factor after a failed solve")
    max_cutbacks: int = _num(10, lo=0, lo_open=False, integer=True, doc="cut-backs allowed in one step")
    placement_first_step: float = _num(0.25, lo=0.0, hi=1.0, lo_open=True, hi_open=False,
                                       doc="first step of the gravity continuation that places the DEA on its "
                                           "obstacle at t = 0 (fraction of g; grows x1.5, cut /4 on failure)")


@dataclass(frozen=True)
class Solver:
    formulation: str = _choice("mixed", ("mixed", "displacement"), "Taylor-Hood u-p or pure displacement")
    electrostatics: str = _choice("energy", ("energy", "coupled"),
                                  "prescribed nominal field, or solve Gauss's law for the potential")
    newton_rtol: float = _pos(1e-8, "relative residual tolerance")
    newton_atol: float = _pos(1e-8, "absolute residual tolerance")
    newton_max_it: int = _num(40, lo=0, integer=True, doc="Newton iterations per attempt")
    jacobian_reuse_ratio: float = _num(0.3, lo=0.0, hi=1.0, lo_open=False, hi_open=True,
                                       doc="keep the factorised Jacobian while each Newton iteration cuts the "
                                           "residual by this factor; 0 = full Newton")
    predictor: str = _choice("quadratic", ("quadratic", "linear"),
                             "first guess of a step: the state extrapolated through the last three accepted "
                             "states (linear through two where the voltage turned or held)")
    line_search_reuse_ratio: float = _num(0.95, lo=0.0, hi=1.0, lo_open=False, hi_open=True,
                                          doc="the same, after a step that the line search damped (a friction's "
                                              "onset or reversal): those iterations cut the residual slowly "
                                              "whatever the Jacobian")
    quadrature_degree: int = _num(4, lo=0, integer=True, doc="quadrature degree of all integrals")
    linear_solver: str = _choice("umfpack", ("mumps", "umfpack", "superlu", "klu", "petsc"),
                                 "sparse direct solver of the Newton steps (PETSc's factor package); the serial "
                                 "ones fall back to mumps when one mesh is split over several ranks")
    coupling_tol_m: float = _pos(1e-10, "coin position change at which the coin-DEA iteration has converged")
    coupling_max_it: int = _num(30, lo=0, integer=True, doc="coin-DEA iterations per step")


@dataclass(frozen=True)
class Mesh:
    cell: str = _choice("hexahedron", ("hexahedron", "tetrahedron"), "cell type of the DEA mesh")
    order: int = _num(2, lo=1, hi=2, lo_open=False, integer=True, doc="polynomial degree of u (pressure: order-1)")
    level: int = _num(0, lo=0, lo_open=False, hi=4, integer=True, doc="uniform refinement: divisions x 2^level")
    n_length: int = _num(16, lo=0, integer=True, doc="divisions along the length (x)")
    n_width: int = _num(2, lo=0, integer=True, doc="divisions across the width (z)")
    n_active: int = _num(1, lo=0, integer=True, doc="divisions through the active stack")
    n_passive: int = _num(1, lo=0, integer=True, doc="divisions through the passive layer")
    coin_size_m: float = _pos(1.5e-3, "target tetrahedron size of the coin mesh")
    symmetry: str = _choice("none", ("none", "half_z"),
                            "half_z: model the half z >= 0 with u_z = 0 on the mid-plane (the scene is symmetric "
                            "in z); forces on the obstacle are doubled; n_width still counts the full width "
                            "(ceil(n_width / 2) divisions across the half: the full mesh's half when even)")
    x_grading: float = _num(1.0, lo=1.0, lo_open=False, hi=20.0,
                            doc="ratio of the element length at the clamp to the one at the free end (>= 1; "
                                "1 = uniform; > 1 refines toward the tip and the coin)")
    underside_grading: float = _num(1.0, lo=1.0, lo_open=False, hi=20.0,
                                    doc="ratio of the largest to the smallest element through the bottom layer, "
                                        "the smallest on the underside, where the DEA touches the coin and the "
                                        "table (>= 1; 1 = uniform; the layer's divisions stay n_active or n_passive)")
    tip_zone_m: float = _nonneg(0.0, "length (x) of the tip zone from the free end, meshed with its own uniform "
                                     "tip_zone_divisions (0: no tip zone); n_length and x_grading mesh the rest")
    tip_zone_divisions: int = _num(4, lo=0, integer=True, doc="divisions along x of the tip zone (beyond the "
                                   "rounded free edge's radius, which its O-grid meshes)")
    rim_band_m: tuple = _floats("[a, b]: the band a <= |z| <= b where the tip's free edge crosses the coin's rim "
                                "(the coin's contact patch), meshed with rim_band_divisions across ([]: no band); "
                                "n_width sets the rest of the width by length")
    rim_band_divisions: int = _num(4, lo=0, integer=True, doc="divisions across the rim band (each side)")
    free_edge_divisions: int = _num(2, lo=0, integer=True, doc="elements along each half of the rounded free "
                                    "edge's arc (dea.free_edge_radius_m), x 2^level")
    rim_band_width_m: float = _nonneg(0.0, "the rim band placed from the coin: this wide, centred on the |z| where the "
                                           "free edge at rest crosses the middle of the coin's rim (0: rim_band_m "
                                           "places it)")


@dataclass(frozen=True)
class Scene:
    """A whole scene; ``coin``/``stop``/``table`` are None when absent."""
    scene: SceneInfo
    dea: DEA
    load: Load
    time: Time
    solver: Solver
    mesh: Mesh
    contact: Contact
    gravity_m_s2: float = _nonneg(9.8, "gravitational acceleration along -y")
    coin: Optional[Coin] = None
    stop: Optional[Stop] = None
    table: Optional[Table] = None
    setup: str = ""
    source_text: str = field(default="", compare=False, repr=False)

    @property
    def has_obstacle(self) -> bool:
        return self.coin is not None or self.stop is not None

    def to_dict(self) -> dict:
        """The resolved scene as a TOML-ready dict (no setups table)."""
        out: dict[str, Any] = {"gravity_m_s2": self.gravity_m_s2}
        for name, cls in SECTIONS.items():
            sec = getattr(self, name)
            if sec is not None:
                out[name] = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(sec).items()}
        out["scene"]["default_setup"] = ""  # setups are already applied
        load = out["load"]
        load["table_t_s"], load["table_V"] = list(load["table_t_s"]), list(load["table_V"])
        out["load"] = {k: v for k, v in load.items() if k in self.load.keys() and not (k == "table_csv" and not v)}
        for section, key in WRITTEN_WHEN_SET:
            sec = getattr(self, section)
            if sec is not None and getattr(sec, key) == _default(type(sec), key):
                del out[section][key]
        return out

    def to_toml(self) -> str:
        """The resolved scene as TOML; loading it again gives the same scene."""
        head = f"# resolved scene {self.scene.name!r}, setup {self.setup!r}\n" if self.setup else ""
        return head + tomli_w.dumps(self.to_dict())


#: keys added after datasets were made: in the resolved scene (``to_toml``, what a dataset records and
#: what a resume compares) only when set away from their default, so that the datasets made before
#: them, which ran at that default, still count as done for the same scene
WRITTEN_WHEN_SET = (("mesh", "underside_grading"), ("mesh", "rim_band_width_m"), ("mesh", "free_edge_divisions"), ("dea", "free_edge_radius_m"),
                    ("coin", "edge_shape"), ("stop", "edge_shape"))


def _default(cls, key: str):
    return next(f.default for f in dataclasses.fields(cls) if f.name == key)


SECTIONS = {"scene": SceneInfo, "dea": DEA, "coin": Coin, "stop": Stop, "table": Table, "contact": Contact,
            "load": Load, "time": Time, "solver": Solver, "mesh": Mesh}
OPTIONAL_SECTIONS = ("coin", "stop", "table")
TOP_LEVEL = {f.name: f for f in dataclasses.fields(Scene) if f.name == "gravity_m_s2"}


# --- validation ----------------------------------------------------------------------

def _allowed(meta) -> str:
    kind = meta["kind"]
    if kind == "choice":
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    if kind == "floats":
        return "a list of finite numbers"
    if kind == "str":
        return "a str"
    parts = ["an integer" if kind == "int" else "a finite number"]
    if meta["lo"] is not None:
        parts.append(f"{'>' if meta['lo_open'] else '>='} {meta['lo']:g}")
    if meta["hi"] is not None:
        parts.append(f"{'<' if meta['hi_open'] else '<='} {meta['hi']:g}")
    return " ".join([parts[0]] + (["that is " + " and ".join(parts[1:])] if len(parts) > 1 else []))


def _check_value(key: str, value, meta):
    kind = meta["kind"]
    bad = SceneError(f"{key} = {value!r}: expected {_allowed(meta)}")
    if kind == "choice":
        if value not in meta["choices"]:
            raise bad
        return value
    if kind == "str":
        if not isinstance(value, str):
            raise bad
        return value
    if kind == "floats":
        if not isinstance(value, (list, tuple)) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
            raise bad
        return tuple(float(v) for v in value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise bad
    if kind == "int":
        if isinstance(value, float) and not value.is_integer():
            raise bad
        value = int(value)
    else:
        value = float(value)
        if not math.isfinite(value):
            raise bad
    lo, hi = meta["lo"], meta["hi"]
    if lo is not None and (value <= lo if meta["lo_open"] else value < lo):
        raise bad
    if hi is not None and (value >= hi if meta["hi_open"] else value > hi):
        raise bad
    return value


def _build_section(name: str, cls, data) -> Any:
    if not isinstance(data, dict):
        raise SceneError(f"[{name}] must be a table, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    for key in unknown:
        if f"{name}.{key}" in REPLACED:
            raise SceneError(f"{name}.{key}: no longer a key; {REPLACED[f'{name}.{key}']}")
    if unknown:
        raise SceneError(f"{name}.{unknown[0]}: unknown key; allowed keys in [{name}]: {', '.join(fields)}")
    kwargs = {}
    for fname, f in fields.items():
        key = f"{name}.{fname}"
        if fname in data:
            kwargs[fname] = _check_value(key, data[fname], f.metadata)
        elif f.default is REQUIRED:
            raise SceneError(f"{key}: missing; expected {_allowed(f.metadata)}")
    return cls(**kwargs)


def _check_load(raw: dict, base_dir: Path | None, explicit=frozenset()) -> dict:
    """Refuse ``[load]`` keys the chosen protocol does not take; read a table's CSV file.

    ``explicit``: the keys a setup or ``--set`` assigned. When they switch the protocol
    (``--set load.protocol='sine'`` on a ramp scene), the file's keys of the old protocol
    are dropped; a key that the file and the protocol disagree on, or that was assigned
    for another protocol, is an error.
    """
    raw = dict(raw)
    name = raw.get("protocol", "ramp")
    if name not in protocols.KEYS:
        return raw                          # the choice check names the allowed protocols
    allowed = protocols.COMMON + protocols.KEYS[name]
    known = {f.name for f in dataclasses.fields(Load)}
    switched = "protocol" in explicit
    for key in list(raw):
        if key in known and key not in allowed:
            if switched and key not in explicit:
                del raw[key]                # a key of the file's own protocol
                continue
            raise SceneError(f"load.{key}: not a key of load.protocol = {name!r}; its keys: {', '.join(allowed)}")
    if name == "table":
        path = raw.get("table_csv", "")
        inline = "table_t_s" in raw or "table_V" in raw
        if path and inline:
            raise SceneError("load.table_csv: give either load.table_csv or load.table_t_s and load.table_V, "
                             "not both")
        if not path and not inline:
            raise SceneError("load.table_t_s: missing; load.protocol = 'table' needs load.table_t_s and "
                             "load.table_V, or load.table_csv")
        if path:
            if not isinstance(path, str):
                raise SceneError(f"load.table_csv = {path!r}: expected a str (a CSV file path)")
            csv_path = Path(path)
            if not csv_path.is_absolute() and base_dir is not None and (base_dir / csv_path).is_file():
                csv_path = base_dir / csv_path
            try:
                raw["table_t_s"], raw["table_V"] = protocols.read_table_csv(csv_path)
            except protocols.ProtocolError as err:
                raise SceneError(str(err)) from None
            del raw["table_csv"]            # the resolved scene carries the points themselves
    return raw


def _check_protocol(load: Load) -> None:
    name = load.protocol
    if name == "ramp_hold_ramp" and load.voltage_end_V > load.voltage_max_V:
        raise SceneError(f"load.voltage_end_V = {load.voltage_end_V!r}: must be <= load.voltage_max_V "
                         f"= {load.voltage_max_V!r}")
    if name == "random" and load.segment_min_s > load.segment_max_s:
        raise SceneError(f"load.segment_min_s = {load.segment_min_s!r}: must be <= load.segment_max_s "
                         f"= {load.segment_max_s!r}")
    if name == "table":
        try:
            protocols.check_table(load.table_t_s, load.table_V, load.voltage_max_V)
        except protocols.ProtocolError as err:
            raise SceneError(str(err)) from None


def layout_bottom(scene: Scene) -> float:
    """y of the clamped DEA's underside: the obstacle's top face (0 without one) + dea.clamp_gap_m
    (the convention of :mod:`deapull.meshing.layout`)."""
    obstacle = scene.coin or scene.stop
    return (obstacle.height_m if obstacle else 0.0) + scene.dea.clamp_gap_m


def _check_consistency(scene: Scene) -> None:
    _check_protocol(scene.load)
    d = scene.dea
    if d.film_thickness_m > d.active_thickness_m:
        raise SceneError(f"dea.film_thickness_m = {d.film_thickness_m!r}: must be <= dea.active_thickness_m "
                         f"= {d.active_thickness_m!r}")
    for name in ("coin", "stop"):
        ob = getattr(scene, name)
        if ob is not None and ob.edge_radius_m >= min(ob.radius_m, ob.height_m):
            raise SceneError(f"{name}.edge_radius_m = {ob.edge_radius_m!r}: must be < {name}.radius_m and "
                             f"< {name}.height_m")
    if scene.coin is not None and scene.stop is not None:
        raise SceneError("[coin] and [stop]: a scene has at most one of them")
    m = scene.mesh
    if m.tip_zone_m and not m.tip_zone_m < d.length_m / 2:
        raise SceneError(f"mesh.tip_zone_m = {m.tip_zone_m!r}: must be < half of dea.length_m = {d.length_m!r}")
    if m.rim_band_width_m and m.rim_band_m:
        raise SceneError(f"mesh.rim_band_width_m = {m.rim_band_width_m!r}: give either it (the band follows the "
                         f"coin) or mesh.rim_band_m = {list(m.rim_band_m)!r}, not both")
    if m.rim_band_width_m and not m.rim_band_width_m < 0.4 * d.width_m:
        raise SceneError(f"mesh.rim_band_width_m = {m.rim_band_width_m!r}: must be < 0.4 dea.width_m = "
                         f"{0.4 * d.width_m!r} (the band and its margins fit in the half width)")
    if m.rim_band_width_m and scene.coin is None and scene.stop is None:
        raise SceneError(f"mesh.rim_band_width_m = {m.rim_band_width_m!r}: needs a [coin] or [stop] to follow")
    lower = d.active_thickness_m if d.active_side == "bottom" else d.passive_thickness_m
    if d.free_edge_radius_m and not d.free_edge_radius_m < min(lower, m.tip_zone_m):
        raise SceneError(f"dea.free_edge_radius_m = {d.free_edge_radius_m!r}: must be < the bottom layer's thickness "
                         f"({lower!r}) and < mesh.tip_zone_m = {m.tip_zone_m!r} (a rounded edge is meshed in the "
                         f"tip zone)")
    if d.free_edge_radius_m and m.underside_grading != 1.0:
        raise SceneError(f"mesh.underside_grading = {m.underside_grading!r}: must be 1 with a rounded free edge "
                         f"(dea.free_edge_radius_m = {d.free_edge_radius_m!r}), whose O-grid sets the bottom rows")
    if m.rim_band_m and not (len(m.rim_band_m) == 2 and 0 < m.rim_band_m[0] < m.rim_band_m[1] < d.width_m / 2):
        raise SceneError(f"mesh.rim_band_m = {list(m.rim_band_m)!r}: expected [a, b] with 0 < a < b < "
                         f"dea.width_m / 2 = {d.width_m / 2!r}, or []")
    if scene.table is not None and scene.table.height_m >= layout_bottom(scene):
        raise SceneError(f"table.height_m = {scene.table.height_m!r}: must be below the clamped DEA's underside "
                         f"(y = {layout_bottom(scene)!r})")
    if scene.load.end_time_s < scene.time.dt_max_s:
        raise SceneError(f"load.end_time_s = {scene.load.end_time_s!r}: must be >= time.dt_max_s")
    if scene.time.dt_min_s > scene.time.dt_max_s:
        raise SceneError(f"time.dt_min_s = {scene.time.dt_min_s!r}: must be <= time.dt_max_s "
                         f"= {scene.time.dt_max_s!r}")
    if scene.solver.electrostatics == "coupled" and scene.solver.formulation != "mixed":
        raise SceneError("solver.electrostatics = 'coupled': needs solver.formulation = 'mixed'")
    if scene.dea.poisson_ratio == 0.5 and scene.solver.formulation == "displacement":
        raise SceneError("solver.formulation = 'displacement': not allowed with dea.poisson_ratio = 0.5 "
                         "(use 'mixed' or a Poisson ratio < 0.5)")


def _parse_value(text: str):
    """Parse a ``--set`` value as TOML (numbers, booleans, quoted strings); bare words are strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_override(data: dict, assignment: str) -> None:
    """Apply one ``section.key=value`` (or ``key=value`` for top-level keys) to raw scene data."""
    if "=" not in assignment:
        raise SceneError(f"--set {assignment!r}: expected section.key=value")
    path, text = assignment.split("=", 1)
    _assign(data, path.strip(), _parse_value(text.strip()))


def _select_for_protocol(data: dict, overrides) -> list[str]:
    """The overrides that apply, in order: ``section.key@protocol=value`` (a fidelity's entry for one
    protocol, ``[fidelities.NAME.PROTOCOL]``) applies only when the scene's load protocol, after the
    unqualified overrides, is that protocol; it loses its qualifier. Every qualifier and key is
    checked, applied or not."""
    chosen, qualified = [], []
    for assignment in overrides:
        path, _, value = assignment.partition("=")
        if "@" not in path:
            chosen.append(assignment)
            continue
        key, proto = (part.strip() for part in path.split("@", 1))
        if proto not in protocols.NAMES:
            raise SceneError(f"--set {assignment!r}: unknown protocol {proto!r} after '@'; allowed: "
                             f"{', '.join(protocols.NAMES)}")
        section, _, name = key.partition(".")
        if section == "load":
            raise SceneError(f"--set {assignment!r}: a load key cannot depend on the protocol; allowed after '@': "
                             f"the keys of {', '.join(s for s in SECTIONS if s != 'load')}")
        if section not in SECTIONS or name not in (known := [f.name for f in dataclasses.fields(SECTIONS[section])]):
            raise SceneError(f"--set {assignment!r}: unknown key {key!r}; allowed: "
                             + (f"{section}.{', '.join(known)}" if section in SECTIONS else
                                f"section.key with section one of {', '.join(SECTIONS)}"))
        qualified.append((len(chosen), proto, f"{key}={value}"))
    if not qualified:
        return chosen
    probe = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    for assignment in chosen:
        apply_override(probe, assignment)
    protocol = (probe.get("load") or {}).get("protocol", "ramp")
    for at, proto, assignment in reversed(qualified):   # in place, so a later --set still wins
        if proto == protocol:
            chosen.insert(at, assignment)
    return chosen


def _assign(data: dict, path: str, value) -> None:
    parts = path.split(".")
    if len(parts) == 1:
        if parts[0] not in TOP_LEVEL:
            raise SceneError(f"{parts[0]}: unknown key; top-level keys: {', '.join(TOP_LEVEL)}; "
                             f"others are section.key ({', '.join(SECTIONS)})")
        data[parts[0]] = value
        return
    if len(parts) != 2 or parts[0] not in SECTIONS:
        raise SceneError(f"{path}: unknown key; expected section.key with section one of {', '.join(SECTIONS)}")
    data.setdefault(parts[0], {})[parts[1]] = value


def from_dict(raw: dict, setup: str | None = None, overrides=(), source_text: str = "",
              base_dir: Path | None = None) -> Scene:
    """Validate raw TOML data (plus a setup and ``--set`` overrides) into a :class:`Scene`.

    ``base_dir``: the scene file's folder (relative paths in the scene are read from there).
    """
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in raw.items()}
    setups = data.pop("setups", {})
    data.pop("fidelities", None)   # named override sets, expanded into ``overrides`` (fidelity_overrides)
    info = data.get("scene", {})
    if setup is None and isinstance(info, dict):
        setup = info.get("default_setup") or None
    if setup:
        if setup not in setups:
            allowed = ", ".join(setups) if setups else "none (this scene has no setups)"
            raise SceneError(f"setup = {setup!r}: unknown setup; allowed: {allowed}")
        for key, value in setups[setup].items():
            _assign(data, key, value)
    overrides = _select_for_protocol(data, overrides)
    for assignment in overrides:
        apply_override(data, assignment)
    explicit = {k.split("=", 1)[0].strip() for k in overrides} | set(setups.get(setup, {}) if setup else ())
    explicit_load = frozenset(k.split(".", 1)[1] for k in explicit if k.startswith("load."))
    allowed_top = set(SECTIONS) | set(TOP_LEVEL)
    unknown = sorted(set(data) - allowed_top)
    if unknown:
        raise SceneError(f"{unknown[0]}: unknown key; allowed: {', '.join(sorted(allowed_top))}, setups, fidelities")
    if isinstance(data.get("load"), dict):
        data["load"] = _check_load(data["load"], base_dir, explicit_load)
    kwargs = {}
    for name, cls in SECTIONS.items():
        if name in data:
            kwargs[name] = _build_section(name, cls, data[name])
        elif name in OPTIONAL_SECTIONS:
            kwargs[name] = None
        elif name == "scene":
            raise SceneError("scene.name: missing; every scene needs a [scene] table with name and description")
        else:
            kwargs[name] = cls()
    if "gravity_m_s2" in data:
        kwargs["gravity_m_s2"] = _check_value("gravity_m_s2", data["gravity_m_s2"], TOP_LEVEL["gravity_m_s2"].metadata)
    scene = Scene(**kwargs, setup=setup or "", source_text=source_text)
    _check_consistency(scene)
    return scene


def resolve_path(name_or_path: str | Path) -> Path:
    """A shipped scene name (``coin_pull``) or a path to a TOML file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise SceneError(f"scene = {str(name_or_path)!r}: no such file")
        return p
    candidate = SCENE_DIR / f"{name_or_path}.toml"
    if not candidate.is_file():
        raise SceneError(f"scene = {str(name_or_path)!r}: unknown scene; shipped scenes: {', '.join(list_scenes())}")
    return candidate


def load(name_or_path: str | Path, setup: str | None = None, overrides=()) -> Scene:
    """Load, resolve and validate a scene by shipped name or path."""
    path = resolve_path(name_or_path)
    text = path.read_text()
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"{path}: not valid TOML ({err})") from None
    return from_dict(raw, setup=setup, overrides=overrides, source_text=text, base_dir=path.parent)


def setups_of(name_or_path: str | Path) -> list[str]:
    """Setup names defined by a scene file (empty for scenes without setups)."""
    raw = tomllib.loads(resolve_path(name_or_path).read_text())
    return list(raw.get("setups", {}))


def fidelities_of(name_or_path: str | Path) -> list[str]:
    """Fidelity names defined by a scene file (its ``[fidelities.<name>]`` tables)."""
    raw = tomllib.loads(resolve_path(name_or_path).read_text())
    return list(raw.get("fidelities", {}))


def fidelity_overrides(name_or_path: str | Path, fidelity: str | None) -> tuple[str, ...]:
    """The ``--set`` overrides (``section.key=value``) that a scene's named fidelity stands for.

    A fidelity is a table ``[fidelities.<name>]`` of the scene file, written like a setup's
    (``"mesh.tip_zone_m" = 0.002``): how finely to resolve the same physics (mesh, contact rule,
    penalty, linear solver). None or "" is the file as written. Given as overrides, it is applied
    before the user's ``--set`` (which win) and is recorded in every case and dataset. A sub-table
    named after a load protocol (``[fidelities.resolved.release]``) holds the entries that apply
    only under that protocol (where the contact sits depends on how the run starts); they come as
    ``section.key@protocol=value``, after the fidelity's other entries.
    """
    if not fidelity:
        return ()
    table = tomllib.loads(resolve_path(name_or_path).read_text()).get("fidelities", {})
    if fidelity not in table:
        allowed = ", ".join(table) if table else "none (this scene defines no fidelities)"
        raise SceneError(f"fidelity = {fidelity!r}: unknown fidelity of scene {str(name_or_path)!r}; allowed: {allowed}")

    def text(value):
        return tomli_w.dumps({"v": value})[4:].strip()
    flat = [f"{key}={text(value)}" for key, value in table[fidelity].items() if not isinstance(value, dict)]
    per_protocol = [f"{key}@{proto}={text(value)}" for proto, sub in table[fidelity].items() if isinstance(sub, dict)
                    for key, value in sub.items()]
    return (*flat, *per_protocol)


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))


def describe_keys() -> list[tuple[str, str, str, str]]:
    """(key, default, allowed, description) for every scene key — docs/scene_keys.md's table."""
    rows = [("gravity_m_s2", "9.8", _allowed(TOP_LEVEL["gravity_m_s2"].metadata),
             TOP_LEVEL["gravity_m_s2"].metadata["doc"])]
    for name, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            default = "required" if f.default is REQUIRED else repr(f.default)
            rows.append((f"{name}.{f.name}", default, _allowed(f.metadata), f.metadata["doc"]))
    return rows


def from_resolved_toml(text: str) -> Scene:
    """The scene a dataset was made with, from its ``scene_toml`` attribute.

    Files written before ``contact.penalty_N_m3`` carry ``contact.penalty_scale`` (k_n =
    penalty_scale · E / h_tip, h_tip the tip element's length along x): it is converted, so
    that every dataset this project has written stays readable."""
    raw = tomllib.loads(text)
    contact = raw.get("contact", {})
    if "penalty_scale" in contact:
        mesh, dea = raw.get("mesh", {}), raw.get("dea", {})
        n = mesh.get("n_length", 16) * 2 ** mesh.get("level", 0)
        L, g = dea.get("length_m", 0.040), mesh.get("x_grading", 1.0)
        r = g ** (1.0 / (n - 1)) if g != 1.0 and n > 1 else 1.0
        h_tip = L / n if r == 1.0 else L * (r - 1.0) / (r ** n - 1.0)
        contact["penalty_N_m3"] = contact.pop("penalty_scale") * dea.get("youngs_modulus_Pa", 0.56e6) / h_tip
    return from_dict(raw)


#: the sections that say how finely a scene is solved (its fidelity), not what it holds
DISCRETISATION = ("mesh", "solver", "contact", "time")
#: keys that choose the path to the solution, not the solution (to the Newton and the coupling
#: tolerances): a dataset made with other values is the same fidelity
SOLVER_PATH = (("solver", "jacobian_reuse_ratio"), ("solver", "line_search_reuse_ratio"), ("solver", "predictor"),
               ("solver", "linear_solver"), ("solver", "coupling_tol_m"), ("solver", "newton_atol"))


def _fidelity_dict(scene_dict: dict) -> dict:
    """``scene_dict`` without the :data:`SOLVER_PATH` keys."""
    out = dict(scene_dict)
    for section, key in SOLVER_PATH:
        if isinstance(out.get(section), dict):
            out[section] = {k: v for k, v in out[section].items() if k != key}
    return out


def fidelity_of_resolved(text: str, setup: str | None, scene_file: str | Path | None = None) -> tuple[str | None, str]:
    """The fidelity a dataset of ``setup`` was made at, from its ``scene_toml`` attribute.

    Returns
    -------
    (name, fingerprint)
        ``name``: a ``[fidelities.NAME]`` of the scene file (``scene_file``, default the shipped
        scene the text names), "" for the file as written, None for other overrides or a text
        that does not parse; ``fingerprint``: 12 hex digits of the SHA-256 of the sections of
        :data:`DISCRETISATION` less the :data:`SOLVER_PATH` keys ("" when the text does not parse),
        equal for two runs solved alike.
    """
    import hashlib
    import json
    try:
        made = from_resolved_toml(text)
    except (tomllib.TOMLDecodeError, InputError):
        return None, ""
    made_dict = _fidelity_dict(made.to_dict())
    fingerprint = hashlib.sha256(json.dumps({k: made_dict.get(k) for k in DISCRETISATION}, sort_keys=True,
                                            default=str).encode()).hexdigest()[:12]
    source = scene_file or made.scene.name
    try:
        names = ("", *fidelities_of(source))
        for name in names:
            if _fidelity_dict(load(source, setup=setup or None,
                                   overrides=fidelity_overrides(source, name)).to_dict()) == made_dict:
                return name, fingerprint
    except InputError:
        pass
    return None, fingerprint


def keys_markdown() -> str:
    """docs/scene_keys.md: every scene key with its default, what is allowed and what it means
    (``deapull show-scene --keys`` prints it; a test holds the page equal to it)."""
    head = ["# Scene keys", "",
            "Every key of a scene file (`deapull show-scene --keys` prints this page). A key's section is its",
            "TOML table; `--set section.key=value` overrides one on the command line, validated like the file.", "",
            "| key | default | allowed | meaning |", "|---|---|---|---|"]
    rows = [f"| `{k}` | {d} | {a} | {m.replace('|', '/')} |" for k, d, a, m in describe_keys()]
    return "\n".join(head + rows) + "\n"
