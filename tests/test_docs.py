"""The documentation says what the code does: the Python examples of the README and of docs/ run; every topic,
service, action and parameter the node defines (cgp_sim_ros.interface) is documented in docs/interface.md, is
named in the README's interface table, and is in the shipped parameter file; every docs/ page is linked from the
README; and every relative link of the README, docs/ and benchmarks/README.md reaches an existing file (and, for
a link into a Markdown page, an existing heading)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()
DOCS = REPO / "docs"
DOC_PAGES = sorted(DOCS.glob("*.md"))
INTERFACE_PAGE = DOCS / "interface.md"
# the pages whose links are checked: the ones a user reads from the README on
LINKED_PAGES = [REPO / "README.md", *DOC_PAGES, REPO / "benchmarks" / "README.md"]

PYTHON_BLOCK = re.compile(r"```python\n(.*?)```", flags=re.S)
FENCED_BLOCK = re.compile(r"^```.*?^```", flags=re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)


def test_readme_python_examples_run():
    blocks = PYTHON_BLOCK.findall(README)
    assert blocks, "the README has no Python example"
    for code in blocks:
        out = _run(code)
        assert out.returncode == 0, out.stderr
        assert "t = 1.000 s" in out.stdout


@pytest.mark.parametrize("page", DOC_PAGES, ids=lambda p: p.name)
def test_docs_python_examples_run(page):
    for code in PYTHON_BLOCK.findall(page.read_text()):
        out = _run(code)
        assert out.returncode == 0, f"{page.name}: an example fails:\n{out.stderr}"


def _interface_names():
    from cgp_sim_ros import interface as itf

    names = [v for k, v in vars(itf).items() if k.startswith(("TOPIC_", "SERVICE_", "ACTION_"))]
    assert len(names) > 20, names  # the interface module still defines its names as TOPIC_/SERVICE_/ACTION_
    return [name.replace("{body}", "<body>").replace("{flock}", "<flock>").replace("{robot}", "<robot>")
            for name in names], itf.PARAMETERS


@pytest.mark.parametrize("page", [INTERFACE_PAGE, REPO / "README.md"], ids=["docs/interface.md", "README.md"])
def test_the_whole_interface_is_documented(page):
    text = page.read_text()
    names, parameters = _interface_names()
    for shown in names:
        assert f"`{shown}`" in text, f"{shown} is not documented in {page.relative_to(REPO)}"
    for spec in parameters:
        assert f"`{spec.name}`" in text, f"parameter {spec.name} is not documented in {page.relative_to(REPO)}"


def test_interface_page_lists_every_parameter_with_its_flag():
    from cgp_sim_ros import interface as itf

    text = INTERFACE_PAGE.read_text()
    for spec in itf.PARAMETERS:
        assert re.search(rf"^\| [^|]*`{spec.name}`[^|]*\|", text, flags=re.M), \
            f"parameter {spec.name} has no row in the parameter table of docs/interface.md"
        if spec.flag:
            assert f"`{spec.flag}`" in text, f"flag {spec.flag} is not documented in docs/interface.md"


def test_parameter_file_lists_every_parameter_with_its_default():
    from cgp_sim_ros import interface as itf

    data = yaml.safe_load((REPO / "msgs_config/params/cgp_sim.yaml").read_text())
    params = data["cgp_sim"]["ros__parameters"]
    assert set(params) == {p.name for p in itf.PARAMETERS}
    for spec in itf.PARAMETERS:
        assert params[spec.name] == spec.default and type(params[spec.name]) is type(spec.default), spec.name


def test_every_docs_page_is_linked_from_the_readme():
    assert DOC_PAGES, "docs/ has no pages"
    linked = {(REPO / target.split("#")[0]).resolve() for target in _links(README)}
    for page in DOC_PAGES:
        assert page.resolve() in linked, f"docs/{page.name} is not linked from the README"


def _links(text: str) -> list[str]:
    """The targets of the Markdown links and images of ``text``, outside code."""
    prose = INLINE_CODE.sub("", FENCED_BLOCK.sub("", text))
    return LINK.findall(prose)


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped (hyphens and underscores kept), spaces to
    hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip())  # a link in a heading: its text
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    anchors, seen = set(), {}
    for heading in re.findall(r"^#{1,6} (.+)$", FENCED_BLOCK.sub("", page.read_text()), flags=re.M):
        slug = _slug(heading)
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


@pytest.mark.parametrize("page", LINKED_PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(page):
    targets = _links(page.read_text())
    assert page.name != "README.md" or page.parent != REPO or targets, "the README links to nothing"
    broken = []
    for target in targets:
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:, ...: not a file here
            continue
        path_part, _, anchor = target.partition("#")
        path = (page.parent / path_part).resolve() if path_part else page
        if not path.exists():
            broken.append(f"{target}: no such file")
        elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
            broken.append(f"{target}: no heading #{anchor} in {path.relative_to(REPO)}")
    assert not broken, f"{page.relative_to(REPO)}: broken links:\n" + "\n".join(broken)


def test_slug_follows_githubs_rule():
    # GitHub's rule on headings these pages link to: the anchors the links above are checked against
    assert _slug("Integrators (`world.integrator`)") == "integrators-worldintegrator"
    assert _slug("Couzin's zonal model") == "couzins-zonal-model"
    assert _slug("The step pipeline (`World.step`, one tick of `dt = 1 / rate_hz`)") == \
        "the-step-pipeline-worldstep-one-tick-of-dt--1--rate_hz"
