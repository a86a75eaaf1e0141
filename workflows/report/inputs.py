"""Where the report reads each study's outputs, and the make steps that make them.

:class:`Inputs` holds the paths (defaults: the folders the make targets write); :data:`STEPS`
names each make target, its command and what it makes; :func:`missing_steps` lists the
targets whose outputs are absent (``make report FULL=1`` runs them first).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from deapull import dataset
from deapull.workflows.sweep import PROTOCOL_SETS

SCENE = "coin_pull"
SETUPS = tuple(f"C{i}" for i in range(1, 9))
#: the coins `make sweep PROTOCOLS=excitation` plays the excitation protocols on
EXCITATION_SETUPS = ("C1", "C3", "C5", "C7")
#: the committed contact reference (``make fem-study``: studies/contact_reference.toml)
REFERENCE_JSON = Path(__file__).resolve().parents[2] / "bench" / "reference" / "contact_reference.json"


@dataclass(frozen=True)
class Inputs:
    """Where each study's outputs are read from (defaults: the make targets' folders)."""
    data: Path = Path("data")
    fields: Path = Path("out/report_fields/C3_fields.xdmf")
    fidelity: Path = Path("out/fidelity")
    stability: Path = Path("out/stability")
    experiments: Path = Path("out/experiments")
    control: Path = Path("out/control")
    control_fem: Path = Path("out/control_fem")
    bench_control: Path = Path("out/bench_control")
    bench_fem: Path = Path("out/bench_fem")
    excitation: Path = Path("data/excitation")
    protocols: Path = Path("out/protocols")
    fem_study: Path = Path("out/fem_study")
    reference: Path = REFERENCE_JSON

    @classmethod
    def under(cls, out_root="out", data="data", **paths) -> "Inputs":
        """Every study folder under ``out_root`` unless given in ``paths`` (None: the default)."""
        root = Path(out_root)
        default = {"fields": root / "report_fields" / "C3_fields.xdmf", "fidelity": root / "fidelity",
                   "stability": root / "stability", "experiments": root / "experiments",
                   "control": root / "control", "control_fem": root / "control_fem",
                   "bench_control": root / "bench_control",
                   "bench_fem": root / "bench_fem", "excitation": Path(data) / "excitation",
                   "protocols": root / "protocols", "fem_study": root / "fem_study", "reference": REFERENCE_JSON}
        default.update({k: Path(v) for k, v in paths.items() if v is not None})
        return cls(data=Path(data), **default)


@dataclass(frozen=True)
class Step:
    """A make target and the command behind it, and the files that show it has run.

    ``command`` is a template over the :class:`Inputs` fields (``{data}``, ``{stability}``, …) and
    ``{out}``, the folder the make targets' ``OUT`` names; ``output`` is the field whose
    folder the target writes (:meth:`hint` reads ``OUT``/``DATA`` from it)."""
    name: str
    command: str
    what: str
    output: str
    target: str = ""        # the make target and its variables ("" = the step's name)

    @property
    def make(self) -> str:
        return f"make {self.target or self.name}"

    def hint(self, inputs: "Inputs") -> tuple[str, str]:
        """(make line, command) that make this step's outputs where ``inputs`` reads them: the
        make line adds ``OUT=``/``DATA=`` where they are not the defaults (out, data)."""
        data = Path(inputs.data)
        written = Path(getattr(inputs, self.output))
        out = (written.parent.parent if self.output == "fields" else written.parent)
        extra = []
        if self.output not in ("data", "excitation") and out != Path("out"):
            extra.append(f"OUT={out}")
        if data != Path("data"):
            extra.append(f"DATA={data}")
        paths = {f: str(getattr(inputs, f)) for f in inputs.__dataclass_fields__}
        return " ".join([self.make, *extra]), self.command.format(out=out, **paths)


STEPS = (
    Step("sweep", "mpirun -n 2 deapull sweep --scene coin_pull --out {data}",
         "the 8 FEM datasets C1..C8 (the sweep, the surrogates and control read them)", "data"),
    Step("report-fields", "deapull solve --scene coin_pull --setup C3 --out {out}/report_fields "
         "--fields-every 10", "the displacement fields of one run (pictures and animation)", "fields"),
    Step("fem-study", "mpirun -n 2 deapull fem-study --study contact_reference --out {out}/fem_study "
         "--publish bench/reference", "the contact reference: mesh ladders, their orders and bound", "fem_study"),
    Step("bench-fem", "python bench/bench_fem.py --out {bench_fem} --np 2",
         "the FEM's wall time, travel error and sweep time beside ABAQUS (docs/fem_accuracy.md)", "bench_fem",
         "bench BENCH=fem"),
    Step("fidelity", "mpirun -n 2 deapull fidelity --scene coin_pull --setup C3 --out {fidelity}",
         "the error-against-run-time ladder", "fidelity"),
    Step("stability", "mpirun -n 2 deapull stability --out {stability}",
         "the stiff and extreme cases", "stability"),
    Step("experiments", "deapull experiments --data {data} --out {experiments}",
         "the paper's six experiment sets (Table II, box plot, rollouts)", "experiments"),
    Step("excitation", "mpirun -n 2 deapull sweep --scene coin_pull --setups C1,C3,C5,C7 "
         "--protocols excitation --out {excitation}", "the FEM under ramp-hold-ramp, triangle, release and "
         "random voltages", "excitation", "sweep PROTOCOLS=excitation"),
    Step("experiments-protocols", "deapull experiments-protocols --data {data} --excitation {excitation} "
         "--out {protocols} --ramp-results {experiments}", "the surrogates on held-out protocols and coins",
         "protocols"),
    Step("control", "deapull control --preset surrogate --out {control}",
         "the closed-loop episodes (Fig. 6)", "control"),
    Step("control-fem", "deapull control --preset fem --out {control_fem}", "the MPC on the FEM plant of every setup (and the multi-setpoint task on fem:C3)",
         "control_fem", "control PRESET=fem"),
    Step("bench-control", "python bench/bench_control.py --out {bench_control}", "the MPC step beside mpc.pytorch",
         "bench_control", "bench BENCH=control"),
)
STEP = {s.name: s for s in STEPS}


def step_done(name: str, inputs: Inputs) -> bool:
    """True when the outputs of step ``name`` are there (complete datasets, the study's table)."""
    if name == "sweep":
        return all(dataset.is_complete(inputs.data / f"{s}.nc") for s in SETUPS)
    if name == "report-fields":
        return inputs.fields.is_file() and dataset.is_complete(fields_run(inputs.fields))
    files = {"fem-study": Path(inputs.reference), "fidelity": inputs.fidelity / "fidelity.csv", "stability": inputs.stability / "stability.csv",
             "experiments": inputs.experiments / "experiments.csv", "control": inputs.control / "control.csv",
             "control-fem": inputs.control_fem / "control.csv",
             "bench-control": inputs.bench_control / "bench_control.json",
             "bench-fem": inputs.bench_fem / "bench_fem.json",
             "experiments-protocols": inputs.protocols / "protocols.csv"}
    if name == "excitation":
        return all(dataset.is_complete(inputs.excitation / f"{s}_{p}.nc")
                   for s in EXCITATION_SETUPS for p in PROTOCOL_SETS["excitation"])
    return files[name].is_file()


def missing_steps(inputs: Inputs) -> list[str]:
    """Names of the steps (make targets) whose outputs are absent, in pipeline order."""
    return [s.name for s in STEPS if not step_done(s.name, inputs)]


def fields_run(xdmf: Path) -> Path:
    """The run dataset beside a field file (``C3_fields.xdmf`` → ``C3.nc``)."""
    return xdmf.with_name(xdmf.name.replace("_fields.xdmf", ".nc"))

