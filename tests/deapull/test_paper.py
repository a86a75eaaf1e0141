"""The paper's figures live in deapull/paper.py only: no other module types them (as a number
or inside a string), the scan does find one that does, and the figures match the paper's
source where it is at hand (../shared/seed)."""
import ast
import re
from pathlib import Path

import pytest

from deapull import paper
from tests.conftest import REPO

#: the folders whose Python files may not type a paper figure (tests/ may: they check the page)
FOLDERS = ("deapull", "meshing", "fem_solver", "surrogate", "control", "workflows", "bench", "scripts")
#: the figures as floats: ABAQUS 130 s and 700 points, Table II, the rollout times in ms, 300 V
#: (1.2 and 0.7 are left out as bare numbers: they are also line widths and ratios; their text is
#: caught), and as integers the ones no other use shares (130 and 300 are a dpi and timeouts)
FLOATS = {130.0, 700.0, 0.34e-4, 3.86e-4, 9.86e-4, 3.68e-4, 12.01e-4, 1200.0, 300.0}
INTS = {700, 1200}
#: the figures as text: "130 s", "1.2 s", "0.7 s", "700 points", Fig. 6's counts, Table II, "300 V"
TEXT = re.compile(r"\b130 ?s\b|130 seconds|\b1\.2 ?s\b|\b0\.7 ?s\b|\b700 points|≤ ?200 it|~?10,000|~1,500|"
                  r"\b0\.34\b|\b3\.86\b|\b9\.86\b|\b3\.68\b|\b12\.01\b|\b300 ?V\b")
PAPER_TEX = REPO.parent / "shared" / "seed" / "lahariya2022_dea_paper.tex"


def typed_figures(root: Path, exempt=("deapull/paper.py",)) -> list[str]:
    """``path:line: what`` for every number or string constant in ``root``'s Python files that
    is one of the paper's figures (docstrings and f-string text included)."""
    hits = []
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel in exempt:
                continue
            for node in ast.walk(ast.parse(path.read_text(), filename=rel)):
                if not isinstance(node, ast.Constant) or isinstance(node.value, bool):
                    continue
                v = node.value
                if (isinstance(v, float) and v in FLOATS) or (isinstance(v, int) and v in INTS):
                    hits.append((rel, node.lineno, f"the number {v!r}"))
                elif isinstance(v, str) and (m := TEXT.search(v)):
                    hits.append((rel, node.lineno, f"the text {m.group(0)!r}"))
    return [f"{rel}:{line}: {what}" for rel, line, what in sorted(hits)]


def test_no_module_but_paper_types_a_figure():
    hits = typed_figures(REPO)
    assert not hits, "import these from deapull.paper instead:\n" + "\n".join(hits)


def test_the_scan_finds_a_typed_figure(tmp_path):
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "b.py").write_text('"""Beside ABAQUS."""\nT = 130.0\nprint(f"x {T} y, paper 1.2 s")\n'
                                             'MAE = 0.34e-4\nLINE_WIDTH = 1.2\nDPI = 130\nN = 700\n')
    hits = typed_figures(tmp_path)
    assert [h.split(": ", 1)[1] for h in hits] == ["the number 130.0", "the text '1.2 s'", "the number 3.4e-05",
                                                "the number 700"]
    assert typed_figures(tmp_path, exempt=("bench/b.py",)) == []


@pytest.mark.skipif(not PAPER_TEX.is_file(), reason="the paper's source (../shared/seed) is not beside the checkout")
def test_the_figures_are_the_papers():
    tex = " ".join(PAPER_TEX.read_text().split())
    assert (f"For 1 second of simulation with {paper.ABAQUS_POINTS} points, the FEM model takes "
            f"{paper.ABAQUS_S:g} seconds") in tex
    assert f"takes $\\le$ {paper.ROLLOUT_MS['f'] / 1e3:g} seconds" in tex
    assert (f"({paper.ROLLOUT_MS['nn'] / 1e3:g} and {paper.ROLLOUT_MS['lstm'] / 1e3:g} seconds for $N\\!N$ and "
            "$L\\!S\\!T\\!M$") in tex
    row = {"mae_x_m": "$x_t$ ($1 \\times 10^{-4} m$)", "mae_Fx_N": "F$_{x,t}$ ($1 \\times 10^{-4} N$)",
           "mae_Fy_N": "F$_{y,t}$ ($1 \\times 10^{-4} N$)"}
    for key, label in row.items():
        cells = tex.split(label, 1)[1].split("\\\\", 1)[0].split("&")[1:]
        printed = [re.sub(r"\\textbf\{([^}]*)\}", r"\1", c).strip() for c in cells]
        ours = [f"{paper.TABLE2_MAE[key][m] / 1e-4:.2f}" if m in paper.TABLE2_MAE[key] else "$-$"
                for m in ("f", "lstm", "nn")]
        assert printed == ours, key
    assert f"average {paper.MPC_S_PER_ITERATION:g}\\,s" in tex
    assert (f"\\textit{{SAC policy}} (average {paper.CONTROL['sac'][1] / 1e3:g}\\,s) and \\textit{{PD policy}} "
            f"(average {paper.CONTROL['pd'][1] / 1e3:g}\\,s)") in tex
    assert "The coin reaches the target in $\\le$\\,200 iterations" in tex and paper.CONTROL["mpc"][0] == "≤ 200"
    assert "approximately 10,000, 1500, and 500 iterations" in tex
    assert [paper.CONTROL[k][0] for k in ("sac", "pd", "heur")] == ["~10,000", "~1,500", "~500"]
    assert f"$V_t$ $\\ge$ {paper.CONTACT_LOST_V:g}\\,V" in tex
    assert "displacement of $-$10$^{-\\textrm{5}}$\\,m" in tex and paper.THRESHOLD_M == -1e-5
    assert (f"Inferred $m_c$ converges to $\\le$\\,{paper.INFER_ERROR_PCT:g}\\% error compared to the real value "
            f"within {paper.INFER_MASS_ITERATIONS:,} iterations, while $\\mu_b$, the converges within "
            f"{paper.INFER_MU_B_ITERATIONS} iterations") in tex
    assert f"standard deviation of {paper.CONTROL_NOISE_M:g}\\,m" in tex
    assert (f"number of timesteps {paper.MPC_HORIZON}, LQR iterations to {paper.MPC_LQR_ITERATIONS}") in tex
    assert f"Each dataset contains {paper.DATASET_POINTS[0]}-{paper.DATASET_POINTS[1]} data points" in tex
    assert (f"Poisson’s ratio is {paper.POISSON_RATIO:g} and Young’s modulus is {paper.YOUNGS_MODULUS_PA / 1e6:g} "
            "MPa") in tex
    assert (f"Each DE membrane has {paper.ABAQUS_ELEMENTS_PER_MEMBRANE} elements" in tex
            and f"generate {paper.ABAQUS_COIN_ELEMENTS} elements" in tex)
    assert f"$\\le$\\,{paper.SIM_ERROR_PCT:g}\\% simulation error" in tex
