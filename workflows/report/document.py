"""The page as data: sections of blocks (paragraphs, tables, images, missing steps), the
paper-against-ours claims, and the registry of the files every number came from.

:class:`Report` collects them while the sections are built (:mod:`.assemble`); :mod:`.render`
turns them into HTML and Markdown.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import xarray as xr

from deapull import dataset
from deapull.io import atomic_write
from deapull.workflows.report.inputs import STEP, Inputs


@dataclass
class Table:
    headers: list
    rows: list                 # lists of cells (str)
    anchors: list | None = None   # an id per row (None: no id)
    caption: str = ""
    wrap: bool = False            # text cells: wrap and align left (HTML)


@dataclass
class Section:
    id: str
    title: str
    blocks: list = field(default_factory=list)
    sources: list = field(default_factory=list)     # paths the section's numbers come from
    missing: list = field(default_factory=list)     # (what, step name)

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def table(self, t: Table) -> None:
        self.blocks.append(("table", t))

    def img(self, rel: str, caption: str) -> None:
        self.blocks.append(("img", rel, caption))

    def bullets(self, items) -> None:
        self.blocks.append(("ul", list(items)))

    def data(self, name: str, csv_text: str, label: str) -> None:
        """Offer the numbers behind a figure as a CSV file (``tables/<section id>-<name>.csv`` beside
        index.html, inline in the portable file), linked as ``label``."""
        self.blocks.append(("data", f"{self.id}-{name}.csv", csv_text, label))

    def lack(self, what: str, step: str) -> None:
        self.missing.append((what, step))
        s = STEP[step]
        self.blocks.append(("missing", what, s))


@dataclass
class Claim:
    """One number of the paper beside ours, linked to the row it comes from."""
    what: str
    paper: str
    ours: str
    anchor: str              # the section or table row with our number
    verdict: str = ""
    outcome: str = ""        # one of OUTCOMES, or "" when the row is not judged


#: what a claim says about the paper: its result holds here, it does not, or the row is ours alone
OUTCOMES = ("reproduced", "not reproduced", "beyond the paper")


class Report:
    """Collects the sections, the paper-against-ours claims and the image files; carries what
    every section reads (``inputs``, ``frames``, ``progress``)."""

    def __init__(self, out: Path, inputs: Inputs, frames: int = 30, progress: bool = True):
        self.out = out
        self.inputs = inputs          # where the sections read the studies' outputs
        self.frames = frames          # frames of the animation
        self.progress = progress      # progress bars on
        self.img = out / "img"
        self.sections: list[Section] = []
        self.claims: list[Claim] = []
        self.sources: dict[Path, dict] = {}

    def found(self, path: Path, section: Section, what: str, step: str) -> bool:
        """True and ``path`` registered as a source when it exists; otherwise the section
        says what is missing (``what``, `path` appended) and which make ``step`` makes it."""
        if not Path(path).is_file():
            section.lack(f"{what} `{path}`", step)
            return False
        self.source(path, section)
        return True

    def source(self, path: Path, section: Section) -> str:
        """Register a file a number came from; returns the anchor of its provenance row."""
        path = Path(path)
        key = path.resolve()
        if path.is_absolute() and key.is_relative_to(Path.cwd()):
            path = key.relative_to(Path.cwd())          # shown as the user would type it
        if key not in self.sources:
            self.sources[key] = {"path": str(path), "sections": [], "anchor": f"src-{len(self.sources) + 1}",
                                 **_file_facts(path)}
        if section.id not in self.sources[key]["sections"]:
            self.sources[key]["sections"].append(section.id)
        if path not in section.sources:
            section.sources.append(path)
        return self.sources[key]["anchor"]

    def copy_image(self, src: Path, name: str) -> str:
        """Copy a study's figure beside the page; returns its path relative to the page."""
        data = Path(src).read_bytes()
        atomic_write(self.img / name, lambda p: Path(p).write_bytes(data), suffix=Path(name).suffix)
        return f"img/{name}"


def _file_facts(path: Path) -> dict:
    st = path.stat()
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return {"bytes": st.st_size, "sha256": h.hexdigest()[:12],
            "modified_utc": _dt.datetime.fromtimestamp(st.st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M"),
            "commit": _recorded_commit(path)}


def _recorded_commit(path: Path) -> str:
    """The git commit the file says made it ('' when it says none)."""
    try:
        if path.suffix == ".nc":
            with xr.open_dataset(path, engine=dataset.ENGINE) as ds:
                return str(ds.attrs.get("git_commit", ""))[:12]
        if path.suffix == ".json":
            return str(json.loads(path.read_text()).get("git_commit", ""))[:12]
    except (OSError, ValueError, AttributeError):
        return ""
    return ""

