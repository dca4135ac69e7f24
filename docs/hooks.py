"""MkDocs hooks: the API reference reads the checkout, and pages may show the repository's figures.

* ``graph/`` and ``blocks/`` install as ``evsda.graph`` and ``evsda.blocks`` (pyproject
  ``package-dir``), a layout griffe cannot find from the checkout or from an editable install. The
  hook links them under ``build/docs-api/evsda/`` (ignored by git), the path mkdocstrings searches
  (``mkdocs.yml``), so the reference is that of the checkout whatever is installed.
* The API reference has one page per package (``API_PAGES``), generated here with one
  ``::: module`` per module found in its folder, so a new module is documented without an edit.
* A page links a figure where it lives, e.g. ``../examples/iss_pass.png`` (which also resolves when
  the Markdown is read on a forge). The hook adds ``examples/*.png`` and ``benchmarks/*.png`` to the
  site under those source paths, so MkDocs checks each link and copies the figure once.
"""

from __future__ import annotations

import os
from pathlib import Path

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files, InclusionLevel

ROOT = Path(__file__).resolve().parents[1]
API_SOURCE = ROOT / "build" / "docs-api" / "evsda"
PACKAGES = {"graph": ROOT / "graph", "blocks": ROOT / "blocks"}
FIGURE_FOLDERS = ("examples", "benchmarks")
#: page -> (package, its folder): the package's own docstring, then each of its modules
API_PAGES = {
    "graph": ("evsda.graph", ROOT / "graph"),
    "ports": ("evsda.blocks.ports", ROOT / "blocks" / "ports"),
    "scene": ("evsda.blocks.scene", ROOT / "blocks" / "scene"),
    "optics": ("evsda.blocks.optics", ROOT / "blocks" / "optics"),
    "pixel": ("evsda.blocks.pixel", ROOT / "blocks" / "pixel"),
    "readout": ("evsda.blocks.readout", ROOT / "blocks" / "readout"),
    "detection": ("evsda.blocks.detection", ROOT / "blocks" / "detection"),
    "blocks": ("evsda.blocks", ROOT / "blocks"),
}


@event_priority(100)  # before mkdocstrings reads its search paths (it drops one that does not exist yet)
def on_config(config: MkDocsConfig) -> MkDocsConfig:
    API_SOURCE.mkdir(parents=True, exist_ok=True)
    for name, source in PACKAGES.items():
        link = API_SOURCE / name
        if link.is_symlink() and link.resolve() == source:
            continue
        if link.is_symlink() or link.exists():
            link.unlink()
        os.symlink(source, link, target_is_directory=True)
    return config


def api_page(package: str, folder: Path) -> str:
    """The Markdown of a package's reference page: its docstring, then every module of the folder."""
    modules = sorted(p.stem for p in folder.glob("*.py") if not p.stem.startswith("_"))
    parts = [f"# `{package}`", f"::: {package}\n    options:\n      members: false\n      show_root_heading: false"]
    parts += [f"::: {package}.{module}" for module in modules]
    return "\n\n".join(parts) + "\n"


def on_files(files: Files, config: MkDocsConfig) -> Files:
    for page, (package, folder) in API_PAGES.items():
        files.append(File.generated(config, f"api/{page}.md", content=api_page(package, folder)))
    docs_dir = Path(config.docs_dir)
    for folder in FIGURE_FOLDERS:
        for figure in sorted((ROOT / folder).glob("*.png")):
            relative = figure.relative_to(ROOT).as_posix()
            files.append(File(
                os.path.relpath(figure, docs_dir).replace(os.sep, "/"), str(docs_dir), config.site_dir,
                config.use_directory_urls, dest_uri=relative, inclusion=InclusionLevel.INCLUDED,
            ))  # INCLUDED: a source path starting with '.' would otherwise count as hidden
    return files
