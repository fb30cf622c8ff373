"""Snakemake's HTML report (`snakemake --report results/report.html`) of a finished workflow,
opened in a real headless browser.

One run for the session: config/tiny_all.yaml's whole DAG (every stage, from DEM to the calibrated
model and the Markdown report; tests/conftest.py's tiny_all_run, shared with
tests/test_pipeline_end_to_end.py), then the HTML report. Chromium (Debian's `chromium`, installed
by `bash run.sh test` when root) loads a copy of the report with a small driver script that records
script errors from the first line on, opens every category and subcategory in turn and shows every
figure; the rendered page (--dump-dom) must name every stage the config runs and every figure, with
no script error, and a screenshot of the first page is kept under that workflow's results/. Without
chromium the browser test skips, saying why; the report is still built and checked.
"""

import fnmatch
import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from pipeline.answer import answer_html
from pipeline.report import assemble_report, caption_text
from tests.conftest import TINY_ALL
from tests.test_workflow import ROOT, snakemake

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
# The report's categories, in stage order, and a file each stage writes when the config runs it
# (config/tiny_all.yaml runs every one).
CATEGORIES = {
    "1. The answer": "results/report/answer_*.html",
    "2. DEM datasets": "results/datasets/*/summary.png",
    "3. GNS": "results/gns/*/train/loss_curve.png",
    "4. DoE": "results/doe/*/response_surface.png",
    "5. Inverse design": "results/inverse*/*/*.png",
    "6. Diagnosis": "results/diagnosis/*/residuals.png",
    "7. Calibrated model": "results/calibrated/*/doe_surface.png",
    "8. Runout methods": "results/runout/methods.png",
    "9. Time": "results/report/time_per_stage.png",
}
# figures the run writes that the report leaves out on purpose (many; workflow/report/workflow.rst says where they are)
NOT_EMBEDDED = [
    "results/dem/*/figures/*.png",
    "results/gns/*/evaluation/snapshots/*.png",
    "results/report_screenshot.png",
]
# Before the report's own scripts: every uncaught error and console.error is recorded.
PRELUDE = """<script>
window.__errors = [];
window.addEventListener("error", function (e) { window.__errors.push("uncaught: " + e.message); });
window.addEventListener("unhandledrejection", function (e) { window.__errors.push("rejected: " + e.reason); });
(function (error) {
  console.error = function () {
    window.__errors.push("console.error: " + Array.from(arguments).join(" "));
    error.apply(console, arguments);
  };
})(console.error);
</script>"""
# After them: open every (category, subcategory), record its results table, show every figure and
# record whether it loaded; then write the record into <pre id="report-test"> for --dump-dom.
DRIVER = """<script>
window.addEventListener("load", function () {
  var log = [], views = [], figures = [];
  Object.keys(categories).forEach(function (c) {
    Object.keys(categories[c]).forEach(function (s) { views.push([c, s]); });
  });
  Object.keys(results).forEach(function (path) {
    if (results[path].mime_type.startsWith("image/")) { figures.push(path); }
  });
  function showView(i) {
    if (i === views.length) { return showFigure(0); }
    // through the menu (as a reader goes), so that each subcategory's results table is built anew
    app.setView({ navbarMode: "menu" });
    setTimeout(function () {
      if (i === 0) { log.push("MENU " + JSON.stringify(document.querySelector("nav").innerText)); }
      app.setView({ navbarMode: "subcategory", category: views[i][0], subcategory: views[i][1] });
      setTimeout(function () {
        var table = document.querySelector("table.table-auto");
        log.push("VIEW " + JSON.stringify([views[i][0], views[i][1], table ? table.innerText : null]));
        showView(i + 1);
      }, 100);
    }, 100);
  }
  function showFigure(i) {
    if (i === figures.length) { return finish(); }
    var path = figures[i];
    app.setView({ content: "img", contentPath: results[path].data_uri, resultPath: path });
    var tries = 0;
    (function check() {
      var img = Array.from(document.images).find(function (im) { return im.src === results[path].data_uri; });
      if ((!img || !img.complete || img.naturalWidth === 0) && tries++ < 40) { return setTimeout(check, 50); }
      log.push("FIGURE " + JSON.stringify([path, img ? img.naturalWidth : 0]));
      showFigure(i + 1);
    })();
  }
  function finish() {
    log.push("ERRORS " + JSON.stringify(window.__errors));
    var out = document.createElement("pre");
    out.id = "report-test";
    out.textContent = log.join("\\n") + "\\nDONE";
    document.body.appendChild(out);
  }
  setTimeout(function () { showView(0); }, 200);
});
</script>"""


def test_every_caption_is_a_file_the_markdown_report_can_render():
    rules = "".join(p.read_text() for p in (ROOT / "workflow/rules").glob("*.smk"))
    used = set(re.findall(r'caption="\.\./report/([\w-]+\.rst)"', rules))
    files = {p.name for p in (ROOT / "workflow/report").glob("*.rst")} - {"workflow.rst"}
    assert used == files  # every caption registered exists, and none is orphaned
    for name in sorted(files):
        text = caption_text(ROOT / "workflow/report" / name)
        assert 60 < len(text) < 700, name  # a few sentences
    # the first page draws the answer pages in (the HTML report renders its Jinja)
    assert ":file: {{ res.path.absolute() }}" in (ROOT / "workflow/report/workflow.rst").read_text()


def test_markdown_report_puts_the_registered_caption_under_each_figure(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results/report").mkdir(parents=True)
    (tmp_path / "caption.rst").write_text("What the *figure* shows: L* against t/t*.\n\nWhat to look at.\n")
    (tmp_path / "results/report/stage.md").write_text(
        "Text.\n\n![a figure](../stage/one/figure.png)\n\n![no caption](../stage/one/other.png)\n"
    )
    text = assemble_report(
        [("Stage", "results/report/stage.md")],
        "results/benchmarks",
        "results/report.md",
        "Title",
        "results/report/time.png",
        captions={"results/stage/{name}/figure.png": "caption.rst"},
    )
    caption = "> What the figure shows: L\\* against t/t\\*.\n>\n> What to look at."
    assert f"![a figure](stage/one/figure.png)\n\n{caption}" in text
    assert "![no caption](stage/one/other.png)\n\n## Time per stage" in text
    with pytest.raises(ValueError, match="Jinja"):
        (tmp_path / "jinja.rst").write_text("The {{ snakemake.wildcards.name }} column.")
        caption_text(tmp_path / "jinja.rst")


def test_answer_page_states_model_parameters_fit_and_cost(tmp_path):
    def route(label, key, model, mse, runs, seconds):
        return {
            "route": label,
            "key": key,
            "model": model,
            "parameters": {"friction": 0.41, "restitution": 0.62},
            "seeds": [1, 2, 3, 4],
            "failed": {},
            "mse": mse,
            "mse_se": 0.004,
            "mse_each": [0.05, 0.07, 0.06, 0.09],
            "curves": [[0.0, 1.0, 1.5]] * 4,
            "dem_runs": runs,
            "calibration_seconds": seconds,
        }

    interval = {"name": "friction", "value": 0.41, "low": 0.35, "high": 0.47, "identifiable": True}
    result = {
        "name": "quartz",
        "column": "quartz_a6",
        "model": "base",
        "why": "calibration.model is base. The config says so.",
        "answer": "base, BO on DEM",
        "routes": [route("base, BO on DEM", "model-bayesopt", "base", 0.0661, 20, 96.0)]
        + [route("base, DoE (quadratic)", "base-doe-quadratic", "base", 0.0871, 50, 270.0)],
        "intervals": [interval, dict(interval, name="restitution", low=0.3, high=0.9, identifiable=False)],
        "gns_intervals": None,
        "transfer": None,
        "engine": "builtin",
        "size_scale": 5,
    }
    figure = tmp_path / "calibrated.png"
    figure.write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    page = answer_html(result, figure)
    for text in (
        "quartz: the base model",
        "calibration.model is base.</p>",  # the first sentence of why
        "friction</td><td",
        "[0.35, 0.47]",
        "[0.3, 0.9] not identifiable",
        "MSE <b>0.0661</b> &plusmn; 0.004",
        "4 packings",
        "0.05-0.09",
        "This route: 20 DEM runs and 96 s",
        "4.5 min",
        'src="data:image/png;base64,',
    ):
        assert text in page, text
    assert "<style" not in page and "<html" not in page and page.isascii()


@pytest.fixture(scope="module")
def finished(tiny_all_run):
    """config/tiny_all.yaml's whole DAG (every stage; tests/conftest.py, one run per session), then
    the HTML report: the workflow folder."""
    workdir, *_, own = tiny_all_run
    snakemake(workdir, "--report", "results/report.html", *own, configfile=TINY_ALL)
    return workdir


def embedded(report: Path) -> tuple[dict, dict]:
    """(categories {category: {subcategory: [result path]}}, results {path: record}) as the report
    embeds them for its scripts."""

    def block(name):
        text = re.search(rf'<script id="{name}">(.*?)</script>', report.read_text(), re.S).group(1)
        return json.loads(re.search(r"=\s*(\{.*\})\s*;?\s*$", text.strip(), re.S).group(1))

    return block("categories"), block("results")


@pytest.mark.slow
def test_report_holds_every_stage_and_figure_with_captions(finished):
    results = finished / "results"
    categories, records = embedded(results / "report.html")
    stages = [category for category, path in CATEGORIES.items() if list(finished.glob(path))]
    assert len(stages) == len(CATEGORIES) and sorted(categories) == stages  # tiny_all runs every stage
    for suffix in (".png", ".csv"):  # every figure and table the run wrote, but those left out on purpose
        made = [
            p.relative_to(finished).as_posix()
            for p in results.rglob(f"*{suffix}")
            if not any(fnmatch.fnmatch(p.relative_to(finished).as_posix(), g) for g in NOT_EMBEDDED)
        ]
        assert made and sorted(p for p in records if p.endswith(suffix)) == sorted(made)
    for path, record in records.items():
        assert len(record["caption"]) > 80, f"{path}: no caption"
        assert record["labels"] is None or record["labels"]["result"], path
    # the Markdown report carries the same captions under its figures
    markdown = (results / "report.md").read_text()
    assert "> GNS training: the one-step losses" in markdown
    assert "> A DEM dataset: its cases in parameter space" in markdown


@pytest.mark.slow
@pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (bash run.sh test installs it from Debian when root)"
)
def test_report_renders_in_headless_chromium(finished):
    results = finished / "results"
    categories, records = embedded(results / "report.html")
    page = finished / "report_test.html"
    text = (results / "report.html").read_text()
    head, body = text.index("<head>") + len("<head>"), text.rindex("</body>")  # scripts may hold either tag as text
    page.write_text(text[:head] + PRELUDE + text[head:body] + DRIVER + text[body:])
    browser = [CHROMIUM, "--headless=new", "--disable-gpu", "--no-sandbox", "--enable-logging=stderr", "--v=0"]
    proc = subprocess.run(
        [*browser, "--virtual-time-budget=20000", "--dump-dom", page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    record = re.search(r'<pre id="report-test">(.*?)</pre>', proc.stdout, re.S)
    assert record, f"the driver never finished:\n{proc.stderr[-3000:]}"
    lines = html.unescape(record.group(1)).splitlines()
    assert lines[-1] == "DONE"
    entries = {}
    for line in lines[:-1]:
        kind, value = line.split(" ", 1)
        entries.setdefault(kind, []).append(json.loads(value))
    uncaught = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line and "Uncaught" in line]
    assert entries["ERRORS"] == [[]] and not uncaught, (entries["ERRORS"], uncaught)
    # the menu names every stage; each subcategory's table lists its results
    for category in categories:
        assert category in entries["MENU"][0]
    views = {(c, s): table for c, s, table in entries["VIEW"]}
    assert set(views) == {(c, s) for c in categories for s in categories[c]}
    for (category, subcategory), table in views.items():  # each result listed by its label (or path)
        for path in categories[category][subcategory]:
            assert (records[path]["labels"] or {}).get("result", path) in table, (category, subcategory, path)
    # every figure is shown and loads
    shown = dict(entries["FIGURE"])
    assert sorted(shown) == sorted(p for p in records if p.endswith(".png"))
    assert all(width > 100 for width in shown.values()), shown
    # a screenshot of the first page (the workflow description and the menu of stages)
    screenshot = results / "report_screenshot.png"
    subprocess.run(
        [*browser, "--virtual-time-budget=10000", "--window-size=1400,1000", f"--screenshot={screenshot}"]
        + [(results / "report.html").as_uri()],
        capture_output=True,
        timeout=120,
        check=True,
    )
    assert screenshot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and screenshot.stat().st_size > 20_000
