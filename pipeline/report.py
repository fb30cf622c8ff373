"""The pipeline report: per-stage Markdown fragments stitched into one document, with a table and
a figure of the time spent per stage (from Snakemake `benchmark:` files; cf. Table 5 of the paper).

Conventions (workflow/rules/common.smk repeats them for stage authors):
  - each stage writes results/report/<stage>.md; links inside it are relative to that file;
  - each job benchmarks to results/benchmarks/<stage>/<rule>[/<wildcards>].tsv.
The report rebases the fragments' relative links onto the report's own folder, and puts under
each figure (a Markdown image on a line of its own) the caption its rule registers with report()
for Snakemake's HTML report (workflow/report/<stem>.rst), so a caption is written once. Captions
are plain reStructuredText: no Jinja, which only the HTML report could fill in.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path

from dem.atomic import write_text
from pipeline.benchmarks import StageTime, read_benchmarks

LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s]+)(\))")
IMAGE_LINE = re.compile(r"\s*!\[[^\]]*\]\(([^)\s]+)\)\s*")
MARKDOWN_SPECIAL = re.compile(r"([\\`*_\[\]<>#|])")


def time_table(times: list[StageTime]) -> str:
    """Markdown table of time per stage and rule, with stage subtotals."""
    lines = [
        "| stage | rule | jobs | total (s) | mean per job (s) | max per job (s) | peak memory (MB) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for stage in dict.fromkeys(t.stage for t in times):
        rows = [t for t in times if t.stage == stage]
        for t in rows:
            rss = "" if t.max_rss_mb is None else f"{t.max_rss_mb:.0f}"
            lines.append(
                f"| {stage} | {t.rule} | {t.jobs} | {t.total_s:.1f} | {t.mean_s:.2f} | {t.max_s:.2f} | {rss} |"
            )
        lines.append(
            f"| **{stage}** | all | {sum(t.jobs for t in rows)} | **{sum(t.total_s for t in rows):.1f}** | | | |"
        )
    return "\n".join(lines)


def plot_stage_times(times: list[StageTime], path: str | os.PathLike) -> None:
    """Horizontal bars: total wall time (s, summed over jobs) per stage, split by rule."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dem.plots import save_figure

    stages = list(dict.fromkeys(t.stage for t in times))
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(stages) + 2.0))
    left = {s: 0.0 for s in stages}
    colours = plt.get_cmap("tab20")
    for k, t in enumerate(times):
        ax.barh(t.stage, t.total_s, left=left[t.stage], color=colours(k % 20), label=f"{t.stage}/{t.rule}")
        left[t.stage] += t.total_s
    ax.set(xlabel="wall time summed over jobs (s)", title="time per stage")
    ax.invert_yaxis()
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def rebase_links(markdown: str, from_dir: str | os.PathLike, to_dir: str | os.PathLike) -> str:
    """Rewrite relative Markdown links/images written relative to `from_dir` to be relative to `to_dir`."""

    def fix(match):
        target = match.group(2)
        if re.match(r"^([a-z]+:|/|#)", target):
            return match.group(0)
        return match.group(1) + os.path.relpath(Path(from_dir, target), to_dir) + match.group(3)

    return LINK.sub(fix, markdown)


def caption_text(path: str | os.PathLike) -> str:
    """The caption in reStructuredText file `path` as Markdown-safe plain text: its paragraphs,
    each on one line, markup dropped and Markdown's special characters escaped."""
    from docutils.core import publish_doctree

    text = Path(path).read_text()
    if "{{" in text or "{%" in text:
        raise ValueError(f"caption {path}: Jinja ({{{{ }}}}, {{% %}}) only the HTML report can fill in; write it out")
    doctree = publish_doctree(text, source_path=str(path), settings_overrides={"report_level": 5})
    paragraphs = [" ".join(block.split()) for block in doctree.astext().split("\n\n")]
    return "\n\n".join(MARKDOWN_SPECIAL.sub(r"\\\1", p) for p in paragraphs if p)


def figure_caption(figure: str | os.PathLike, captions: Mapping[str, str]) -> str | None:
    """The caption file of `figure` (a path relative to the working directory): the file of the
    first output pattern in `captions` ({pattern with {wildcards}: caption file}) that it
    matches, or None."""
    figure = Path(os.path.relpath(figure)).as_posix()
    for pattern, caption in captions.items():
        regex = re.sub(r"\\\{\w+(,[^}]*)?\\\}", "[^/]+", re.escape(pattern))
        if re.fullmatch(regex, figure):
            return caption
    return None


def add_captions(markdown: str, fragment_dir: str | os.PathLike, captions: Mapping[str, str]) -> str:
    """`markdown` (links relative to `fragment_dir`) with each figure's caption (figure_caption)
    as a quote under it; figures without one are left as they are."""
    lines = []
    for line in markdown.splitlines():
        lines.append(line)
        image = IMAGE_LINE.fullmatch(line)
        if image is None or re.match(r"^([a-z]+:|/|#)", image.group(1)):
            continue
        caption = figure_caption(Path(fragment_dir, image.group(1)), captions)
        if caption is not None:
            lines += ["", *(f"> {text}" if text else ">" for text in caption_text(caption).splitlines())]
    return "\n".join(lines)


def assemble_report(
    sections: list[tuple[str, str]],
    benchmark_dir: str | os.PathLike,
    out_path: str | os.PathLike,
    title: str,
    time_figure: str | os.PathLike,
    captions: Mapping[str, str] | None = None,
) -> str:
    """Write the report at `out_path`: `title`, one `## <title>` per (title, fragment path) in
    `sections` (links rebased), then the time-per-stage table and figure. captions: {output
    pattern: caption file} (workflow report_captions) for the captions under the figures.
    Returns the text."""
    captions = captions or {}
    out_dir = Path(out_path).parent
    parts = [f"# {title}", ""]
    parts += [f"- [{name}](#{_anchor(name)})" for name, _ in sections] + ["- [Time per stage](#time-per-stage)", ""]
    for name, fragment in sections:
        fragment = Path(fragment)
        if not fragment.exists():
            raise FileNotFoundError(f"report section {name!r}: fragment {fragment} does not exist")
        text = add_captions(fragment.read_text(), fragment.parent, captions)
        text = rebase_links(text, fragment.parent, out_dir)
        parts += [f"## {name}", "", text.strip(), ""]
    times = read_benchmarks(benchmark_dir)
    parts += [
        "## Time per stage",
        "",
        "Wall time of every job, from Snakemake `benchmark:` files "
        f"({os.path.relpath(benchmark_dir, out_dir)}/<stage>/<rule>/...). Jobs run in parallel, so the "
        "elapsed time of a run is shorter than these sums. Files of jobs from earlier configs count too; "
        "delete the folder for a clean tally.",
        "",
    ]
    if times:
        plot_stage_times(times, time_figure)
        figure = f"![time per stage]({os.path.relpath(time_figure, out_dir)})"
        parts += [time_table(times), "", add_captions(figure, out_dir, captions), ""]
    else:
        parts += ["No benchmark files yet.", ""]
    text = "\n".join(parts)
    write_text(out_path, text)
    return text


def _anchor(title: str) -> str:
    return re.sub(r"[^a-z0-9 -]", "", title.lower()).replace(" ", "-")
