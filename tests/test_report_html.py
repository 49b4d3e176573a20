"""report.html (issue 35): self-contained, findings first, every table sortable and filterable (also from the URL's
fragment), each pair's details; every value escaped. One test opens it in a real headless Chromium and reads the
rendered rows back from the DOM after the page's script ran."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path

import pandas as pd
import pytest

import bench
from bench.html import parse_markdown, render_html
from designs import Design, DesignResult

NASTY = '<script>document.title="pwned"</script> & "quoted" </td></tr></table><evil-tag a=\'1\'>'
VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}


# -- a small DOM --------------------------------------------------------------------------------------------
class Node:
    def __init__(self, tag: str, attrs: dict, parent=None):
        self.tag, self.attrs, self.parent, self.children = tag, attrs, parent, []

    def text(self) -> str:
        return "".join(c if isinstance(c, str) else c.text() for c in self.children)

    def all(self, tag: str | None = None, **attrs):
        for c in self.children:
            if isinstance(c, Node):
                if (tag is None or c.tag == tag) and all(c.attrs.get(k.rstrip("_")) == v for k, v in attrs.items()):
                    yield c
                yield from c.all(tag, **attrs)

    def first(self, tag: str | None = None, **attrs):
        return next(self.all(tag, **attrs), None)


class _Builder(HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.root = self.cur = Node("#root", {})
        self.tags: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        node = Node(tag, {k: (v if v is not None else "") for k, v in attrs}, self.cur)
        self.cur.children.append(node)
        if tag not in VOID:
            self.cur = node

    def handle_endtag(self, tag):
        n = self.cur
        while n is not None and n.tag != tag:
            n = n.parent
        if n is not None and n.parent is not None:
            self.cur = n.parent

    def handle_data(self, data):
        self.cur.children.append(data)


def dom(text: str) -> tuple[Node, list[str]]:
    b = _Builder()
    b.feed(text)
    b.close()
    return b.root, b.tags


def _rows(table: Node) -> list[tuple[bool, list[Node]]]:
    """(hidden, cells of the main row) of each pair of the results table, in document order."""
    return [("hidden" in tb.attrs, list(tb.first("tr", class_="main").all("td"))) for tb in _bodies(table)]


def _bodies(table: Node) -> list[Node]:
    """The table's own tbody elements (not those of the tables in a pair's details)."""
    return [c for c in table.children if isinstance(c, Node) and c.tag == "tbody"]


# -- markdown and escaping (no browser) ----------------------------------------------------------------------
def test_parse_markdown_reads_what_render_markdown_writes():
    text = "\n".join([
        "# title", "", "Intro `code` here.", "", "## Section one", "",
        "- first item", "  continued", "  - nested", "- second", "",
        "| a | b \\| c |", "|---|---|", "| 1 | x \\| y |", "| 2 |  |", "",
        "![a caption](figures/x.png)", "", "*a caption*", "", "### sub", "", "A paragraph", "on two lines.",
    ])
    blocks = parse_markdown(text)
    assert blocks[0] == ("h", 1, "title") and blocks[1] == ("p", "Intro `code` here.")
    assert blocks[3] == ("list", [(0, "first item\ncontinued"), (1, "nested"), (0, "second")])
    assert blocks[4] == ("table", ["a", "b | c"], [["1", "x | y"], ["2", ""]])
    assert blocks[5] == ("img", "a caption", "figures/x.png")
    assert blocks[-1] == ("p", "A paragraph on two lines.")


def test_every_value_is_escaped(tmp_path):
    table = pd.DataFrame({"plant": ['<b>p&"x"</b>'], "design": ["d"], "status": ["error"], "reason": [NASTY[:60]],
                          "decay_rate": [float("nan")], "details": [NASTY]})
    gains = [{"plant": '<b>p&"x"</b>', "design": "d", "K": [[1.0]], "F": [[2.0]], "best": NASTY,
              "certificate": {"paper": {"status": NASTY, "P": [[1.0]]}}, "from_x0": None}]
    md = f"# report <i>\n\n## What the suite found\n\n- **{NASTY}**\n\n## T\n\n| x |\n|---|\n| {NASTY} |\n"
    page = render_html(md, table, gains, tmp_path)
    root, tags = dom(page)
    assert tags.count("script") == 1 and "evil-tag" not in tags and "i" not in tags  # only the page's own script
    assert root.first("title").text() == "report <i>"
    results = root.first("table", id="results")
    (hidden, cells), = _rows(results)
    assert [c.text() for c in cells[1:3]] == ['<b>p&"x"</b>', "d"]
    assert NASTY in results.text()  # the details, the best level and the certificate's status, as text
    assert NASTY in root.first("table", id="t").text() and NASTY in root.first("section").text()
    assert cells[1].attrs["title"] == '<b>p&"x"</b>'


def test_the_page_opens_with_the_findings_and_holds_every_section(tmp_path):
    md = ("# oslbench report\n\nCommand: `x`.\n\n## Feasibility\n\n| plant | d |\n|---|---|\n| p | ok |\n\n"
          "## What the suite found\n\n- **p**: found.\n\n## A section added later\n\n| k | v |\n|---|---|\n| 1 | 2 |\n")
    table = pd.DataFrame({"plant": ["p"], "design": ["d"], "a_new_column": [3.5], "details": [""]})
    root, _ = dom(render_html(md, table, [], tmp_path))
    heads = [s.first("h2").text() for s in root.all("section")]
    assert heads == ["What the suite found", "This run", "Results by pair", "Feasibility", "A section added later"]
    tables = [t.attrs["id"] for t in root.all("table") if "data" in t.attrs.get("class", "").split()]
    assert tables == ["results", "feasibility", "a-section-added-later"]  # every table sortable and filterable
    assert [b.attrs["data-table"] for b in root.all("input", class_="filter")] == tables
    header = [th.attrs.get("data-name") for th in root.first("table", id="results").all("th")]
    assert header == [None, "plant", "design", "a_new_column"]  # every column of the table, none named in the code
    assert "No gains" in root.first("tr", class_="detail").text()


# -- in a browser ------------------------------------------------------------------------------------------------
def _chromium() -> str | None:
    return next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


@dataclass(frozen=True, kw_only=True)
class Nasty(Design):
    """A design whose reason holds markup."""

    def design(self, plant, constants):
        return DesignResult(status="inapplicable", reason=NASTY)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    folder = tmp_path_factory.mktemp("html")
    res = bench.run(plants=["flexible_link", "pendulum_v1"],
                    designs=["paper_gains", "lqr+lqe", "lqr+rajamani", "lqr+zhang_osl", Nasty()], jobs=1,
                    progress=False)
    res.write(folder)
    return folder


def _open(page: Path, fragment: str, tmp_path: Path) -> Node:
    """The DOM Chromium holds after loading ``page#fragment`` and running its script."""
    browser = _chromium()
    profile = tmp_path / f"profile-{abs(hash(fragment))}"
    done = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                           "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-extensions",
                           f"--user-data-dir={profile}", "--virtual-time-budget=5000", "--dump-dom",
                           f"{page.resolve().as_uri()}#{fragment}"], capture_output=True, text=True, timeout=180)
    assert done.returncode == 0 and "<html" in done.stdout, done.stderr[-2000:]
    return dom(done.stdout)[0]


@pytest.mark.skipif(_chromium() is None, reason="no chromium on this machine (apt-get install chromium; .ci/run does)")
def test_a_browser_filters_and_sorts_the_results_from_the_fragment(report, tmp_path):
    csv = pd.read_csv(report / "results.csv", keep_default_na=False)
    root = _open(report / "report.html", "table=results&filter=flexible_link&sort=decay_rate", tmp_path)
    assert root.first("body").attrs.get("data-ready") == "1"  # the script ran
    assert root.first("title").text() == "oslbench report"  # the reason's script is text, not code
    table = root.first("table", id="results")
    header = [th.attrs.get("data-name") for th in table.first("thead").all("th")]
    plant, design, decay = header.index("plant"), header.index("design"), header.index("decay_rate")
    rows = _rows(table)
    assert len(rows) == len(csv) == 10
    shown = [(c[plant].text(), c[design].text(), c[decay].attrs.get("data-v")) for hidden, c in rows if not hidden]
    # independently: the flexible link's pairs by decay rate, smallest first, ties in the table's order, blanks last
    want = csv[csv["plant"] == "flexible_link"].copy()
    want["rate"] = pd.to_numeric(want["decay_rate"].replace("", float("nan")))
    want = want.sort_values("rate", na_position="last", kind="stable")
    assert [(p, d) for p, d, _ in shown] == list(zip(want["plant"], want["design"]))
    assert [d for _, d, _ in shown] != list(csv[csv["plant"] == "flexible_link"]["design"])  # the sort moved rows
    rates = [float(v) for _, _, v in shown if v is not None]
    assert rates == sorted(rates) and len(rates) >= 2 and shown[-1][2] is None  # a blank rate last
    hidden = {(c[plant].text(), c[design].text()) for h, c in rows if h}
    assert hidden == set(zip(csv["plant"], csv["design"])) - {(p, d) for p, d, _ in shown}
    assert table.first("th", **{"data-name": "decay_rate"}).attrs.get("aria-sort") == "ascending"
    count = root.first("span", class_="count", **{"data-table": "results"}).text()
    assert count == f"{len(shown)} of 10 rows"
    # the other tables are left alone (table=results): all rows shown
    other = root.first("table", id="feasibility-and-verdicts")
    assert other is not None and not any("hidden" in tr.attrs for tr in other.first("tbody").all("tr"))
    # the reason with markup is text in the pair's details, and no element of it exists
    nasty = [tb for tb in _bodies(table) if NASTY in tb.text()]
    assert len(nasty) == 2 and root.first("evil-tag") is None
    assert len(list(root.all("script"))) == 1
    # every word must match: the pendulum's LQR pairs
    table = _open(report / "report.html", "table=results&filter=lqr%20PENDULUM", tmp_path).first("table", id="results")
    shown = {(c[plant].text(), c[design].text()) for hidden, c in _rows(table) if not hidden}
    assert shown == {(p, d) for p, d in zip(csv["plant"], csv["design"]) if p == "pendulum_v1" and d.startswith("lqr+")}


@pytest.mark.skipif(_chromium() is None, reason="no chromium on this machine (apt-get install chromium; .ci/run does)")
def test_a_browser_sorts_a_report_table_by_text_keeping_ties_in_order(report, tmp_path):
    root = _open(report / "report.html", "sort=-plant", tmp_path)
    table = root.first("table", id="certified-decay-rate-by-level")
    names = [th.attrs.get("data-name") for th in table.first("thead").all("th")]
    got = [[td.text() for td in tr.all("td")] for tr in _bodies(table)[0].all("tr")]
    md = (report / "REPORT.md").read_text(encoding="utf-8")
    section = md[md.index("## Certified decay rate by level"):].split("\n## ")[0]
    lines = [ln for ln in section.splitlines()[1:] if ln.startswith("|")]
    original = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines[2:]]
    k = names.index("plant")
    assert got == sorted(original, key=lambda r: r[k], reverse=True)  # Python's sort is stable in reverse too
    assert got != original  # the order changed: pendulum_v1 first
    assert table.first("th", **{"data-name": "plant"}).attrs.get("aria-sort") == "descending"
