"""The documentation: the site builds strictly and offline (`mkdocs build --strict`: every link, anchor, page in the
nav, included table and API object resolves), the generated tables it shows are the generators' files, the short
README's links reach the docs in one click, its results table is results/table.md, and its test command is
.ci/run's."""
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# plugins that would fetch at build time (fonts, images, git history, remote content) must stay out
FETCHING = {"social", "privacy", "blog", "optimize", "git-revision-date-localized", "git-committers", "rss"}


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built from the repository into a temporary folder, with any network access refused (proxies
    pointing at a closed port): a plugin that fetches fails the strict build instead of passing on a connected
    machine."""
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "HTTP_PROXY": "http://127.0.0.1:9", "HTTPS_PROXY":
           "http://127.0.0.1:9", "http_proxy": "http://127.0.0.1:9", "https_proxy": "http://127.0.0.1:9"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d",
                           str(out)], cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "WARNING" not in proc.stderr, proc.stderr[-3000:]
    return out


def _html(site: Path, page: str) -> str:
    """The built HTML of docs/<page> (a .md path relative to docs/)."""
    rel = Path(page).with_suffix("")
    return (site / ("index.html" if rel.name == "index" else rel / "index.html")).read_text(encoding="utf-8")


def test_the_config_has_no_plugin_that_fetches():
    class Loader(yaml.SafeLoader):
        pass
    Loader.add_constructor("!relative", lambda loader, node: loader.construct_scalar(node))   # mkdocs' own tag
    cfg = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=Loader)
    names = {p if isinstance(p, str) else next(iter(p)) for p in cfg["plugins"]}
    assert names == {"search", "mkdocstrings"} and not names & FETCHING
    assert cfg["strict"] is True and cfg["theme"]["font"] is False      # no Google Fonts request from the browser


def test_the_generated_tables_are_included_and_rendered(site):
    """Each results/*.md is included (not copied) by exactly one page, and its rows reach the HTML."""
    pages = sorted((ROOT / "docs").rglob("*.md"))
    tables = sorted((ROOT / "results").glob("*.md"))
    assert len(tables) == 7
    for table in tables:
        line = f'--8<-- "results/{table.name}"'
        including = [p for p in pages if line in p.read_text(encoding="utf-8").split("\n")]
        assert len(including) == 1, (table.name, including)
        body = table.read_text(encoding="utf-8").strip()
        assert body not in including[0].read_text(encoding="utf-8")
        page = html.unescape(re.sub(r"</?code>", "", _html(site, including[0].relative_to(ROOT / "docs").as_posix())))
        rows = [r for r in body.splitlines() if r.startswith("|") and not r.startswith("|--")][-1]
        cells = [c.strip() for c in rows.strip("|").split("|")]
        first, last = cells[0].replace("`", ""), cells[-1]
        assert f"<td>{first}" in page and last.replace("`", "") in page, (table.name, cells)
    for page in pages:
        assert "--8<--" not in _html(site, page.relative_to(ROOT / "docs").as_posix())


def test_the_api_reference_is_generated_from_the_docstrings(site):
    """The reference pages hold the public objects (mkdocstrings reads the sources; a renamed object fails the
    strict build)."""
    for page, names in {"reference/kexp.md": ["kexp.identify.estimator.fit", "kexp.identify.estimator.FittedModel"],
                        "reference/systems.md": ["kexp.systems.make_system", "kexp.systems.ControlAffineSystem"],
                        "reference/identify.md": ["kexp.identify.identify.identify", "kexp.identify.KoopmanBilinearModel"],
                        "reference/clf.md": ["kexp.clf.synthesize_clf", "kexp.clf.check_certificate"],
                        "reference/control.md": ["kexp.control.Lmpc", "kexp.control.make_law"],
                        "reference/recording.md": ["kexp.recording.writer.RunLogger",
                                                   "kexp.recording.diff.diff_logs",
                                                   "kexp.recording.reader.read_log"]}.items():
        html = _html(site, page)
        for name in names:
            assert f'id="{name}"' in html, (page, name)


def test_every_readme_link_resolves_in_one_click(site):
    text = README.read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    docs = [link for link in links if link.startswith("docs/") and link.split("#")[0].endswith(".md")]
    assert len(docs) >= 17            # each user path of the map
    for link in links:
        if link.startswith(("http://", "https://", "#")):
            continue
        path, _, anchor = link.partition("#")
        assert (ROOT / path).is_file(), f"README links to {link}: no such file"
        if anchor:
            assert f'id="{anchor}"' in _html(site, path.removeprefix("docs/")), link
    for anchor in re.findall(r"\]\(#([^)]+)\)", text):
        slugs = [re.sub(r"[^\w\- ]", "", h.lower()).strip().replace(" ", "-")
                 for h in re.findall(r"^#+ (.*)$", text, re.M)]
        assert anchor in slugs, anchor
    for guide in ["configs", "own-system", "data-from-files", "noise", "sweeps", "rerun", "foxglove", "diff",
                  "pytest-plugin"]:
        assert f"(docs/guides/{guide}.md)" in text, guide


def test_the_readme_is_short_and_its_results_table_is_the_generated_one():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 110 and len(text.encode()) <= 8000
    block = text.split("<!-- results table: generated, see results/table.md -->\n", 1)[1]
    block = block.split("<!-- end of results table -->", 1)[0]
    assert block.strip() == (ROOT / "results" / "table.md").read_text(encoding="utf-8").strip()
    image = re.search(r"!\[[^]]*\]\((docs/figures/\w+\.png)\)", text).group(1)
    assert (ROOT / image).stat().st_size < 200_000
    assert "../shared" not in text and "<host>" not in text
    assert "MIT License" in (ROOT / "LICENSE").read_text() and "the kexp authors" in (ROOT / "LICENSE").read_text()


def test_ci_runs_exactly_the_readme_test_command():
    command = "pip install -e '.[test]' && python -m pytest -q"
    readme_lines = [ln.split("#")[0].strip() for ln in README.read_text(encoding="utf-8").splitlines()]
    assert command in readme_lines
    started = [ln.split("#")[0].strip() for ln in (ROOT / "docs" / "getting-started.md").read_text().splitlines()]
    assert command in started
    ci = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.strip()]
    assert ci[-1] == command
