"""The report's formats: one self-contained HTML page, its Markdown summary, and
``validation/README.md`` (the baselines' table). Pure functions of the entries that
:mod:`validation.report` gathers; nothing here runs a case."""
from __future__ import annotations

import base64
import html
import time

from validation.registry import is_rows

CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:72em;color:#222;line-height:1.35}
h1{font-size:1.5em}h2{font-size:1.15em;margin:0}
table{border-collapse:collapse;font-size:.85em;margin:.4em 0}
td,th{border:1px solid #ccc;padding:.15em .5em;text-align:left;vertical-align:top}
th{background:#f2f2f2}td.num{text-align:right;font-family:ui-monospace,monospace}
section{border:1px solid #ddd;border-radius:6px;padding:.8em 1em;margin:1em 0}
.badge{display:inline-block;white-space:nowrap;padding:.05em .6em;border-radius:1em;font-weight:600;font-size:.85em}
.pass{background:#d6f5d6;color:#135e13}.fail{background:#fbd5d5;color:#8a1212}
.none{background:#eee;color:#555}.stale{background:#fff1c2;color:#7a5a00}
.raised{background:#8a1212;color:#fff}
.meta{color:#555;font-size:.85em}img{max-width:48%;margin:.3em;border:1px solid #eee}
"""


def esc(x) -> str:
    return html.escape(str(x))


def fmt(v) -> str:
    """A figure as text: floats with 6 significant digits, lists and objects summarised."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return format(v, ".6g")
    if isinstance(v, list):
        return f"[{len(v)} items]" if len(v) > 6 else ", ".join(fmt(x) for x in v)
    if isinstance(v, dict):
        return f"{{{len(v)} keys}}"
    return str(v)


def verdict(e: dict) -> tuple[str, str]:
    """(css class, text) of a case's badge."""
    if e["raised"]:
        return "raised", "raised"
    if e["pass"] is True:
        return "pass", "pass"
    if e["pass"] is False:
        return "fail", "fail"
    return "none", "no verdict" if e["baseline"] or e["run"] else "no baseline"


def stale_text(e: dict) -> str:
    """'' when current; else why the baseline is stale."""
    if not e["baseline"]:
        return ""
    if e["stale"] is None:
        return "stale: its commit is unknown to git"
    if e["stale"]:
        more = f" and {len(e['stale']) - 5} more" if len(e["stale"]) > 5 else ""
        return "stale: changed since " + ", ".join(e["stale"][:5]) + more
    return ""


def figure_rows(e: dict) -> list[tuple[str, str, str]]:
    """(figure, now, baseline) for every scalar figure of the run or the baseline."""
    now = (e["run"] or {}).get("figures") or {}
    base = (e["baseline"] or {}).get("figures") or {}
    keys = list(dict.fromkeys([*now, *base]))
    skip = {"case", "pass"}
    return [(k, fmt(now[k]) if k in now else "", fmt(base[k]) if k in base else "")
            for k in keys if k not in skip and not is_rows(now.get(k, base.get(k)))]


def rows_html(name: str, rows: list[dict]) -> str:
    cols = list(dict.fromkeys(k for r in rows for k in r))
    head = "".join(f"<th>{esc(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td class=num>{esc(fmt(r.get(c, '')))}</td>" for c in cols)
                   + "</tr>" for r in rows)
    return (f"<details><summary>{esc(name)} ({len(rows)} rows)</summary>"
            f"<table><tr>{head}</tr>{body}</table></details>")


def _img(path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    when = time.strftime("%Y-%m-%d %H:%M", time.gmtime(path.stat().st_mtime))
    return (f'<img alt="{esc(path.name)}" title="{esc(path.name)} ({when} UTC)" '
            f'src="data:image/png;base64,{data}">')


def case_html(e: dict) -> str:
    """One case's section: badge, target, figures now and in the baseline, tables, plots."""
    cls, text = verdict(e)
    st = stale_text(e)
    parts = [f'<section id="{esc(e["name"])}"><h2>{esc(e["name"])} '
             f'<span class="badge {cls}">{text}</span>'
             + (f' <span class="badge stale">stale</span>' if st else "") + "</h2>",
             f"<p>{esc(e['summary'])}</p>",
             f"<p><b>Target (the pass rule):</b> {esc(e['target'] or 'not stated in the registry: its pass figure as the case computes it')}</p>"]
    if e["run"]:
        parts.append(f"<p class=meta>This run: {esc(e['run']['command'])}, {e['run']['status']}, "
                     f"{e['run']['wall_s']:.1f} s wall.</p>")
    if e["baseline"]:
        p = e["baseline"]["provenance"]
        parts.append(f"<p class=meta>Baseline <code>{esc(e['baseline']['file'])}</code>: commit "
                     f"{esc(p['commit'])}, {esc(p['date'])}, {esc(p['machine'])}, load "
                     f"{esc(p.get('load', '?'))}, wall {esc(fmt(p.get('wall_s', '?')))} s; "
                     f"command <code>{esc(p['command'])}</code>.</p>")
        if st:
            parts.append(f"<p class=meta><b>{esc(st)}</b></p>")
    else:
        parts.append("<p class=meta>No baseline recorded (<code>python -m validation "
                     f"{esc(e['name'])} --record</code>).</p>")
    rows = figure_rows(e)
    if rows:
        parts.append("<table><tr><th>figure</th><th>this run</th><th>baseline</th></tr>"
                     + "".join(f"<tr><td>{esc(k)}</td><td class=num>{esc(a)}</td>"
                               f"<td class=num>{esc(b)}</td></tr>" for k, a, b in rows)
                     + "</table>")
    for label, src in (("this run", e["run"]), ("baseline", e["baseline"])):
        for k, v in ((src or {}).get("figures") or {}).items():
            if is_rows(v):
                parts.append(rows_html(f"{k}, {label}", v))
    if e["plots"]:
        newest = max(p.stat().st_mtime for p in e["plots"])
        parts.append(f"<p class=meta>Plots: <code>validation/out/{esc(e['name'])}/</code>, "
                     f"{len(e['plots'])} PNG files (at most 12, newest first), last written "
                     f"{time.strftime('%Y-%m-%d %H:%M', time.gmtime(newest))} UTC (by the last "
                     "local run, which may not be the baseline's).</p><div>"
                     + "".join(_img(p) for p in e["plots"]) + "</div>")
    return "\n".join(parts) + "</section>"


def index_html(entries: list[dict]) -> str:
    """The overview table at the top: one row a case, linked to its section."""
    rows = []
    for e in entries:
        cls, text = verdict(e)
        b = e["baseline"]
        prov = f"{b['provenance']['commit']}, {str(b['provenance']['date'])[:10]}" if b else ""
        wall = (e["run"] or {}).get("wall_s") or ((b or {}).get("provenance") or {}).get("wall_s")
        st = '<span class="badge stale">stale</span>' if stale_text(e) else ""
        rows.append(f'<tr><td><a href="#{esc(e["name"])}">{esc(e["name"])}</a></td>'
                    f'<td><span class="badge {cls}">{text}</span></td><td>{st}</td>'
                    f"<td>{esc(prov)}</td><td class=num>{esc(fmt(wall)) if wall else ''}</td>"
                    f"<td>{esc(e['summary'])}</td></tr>")
    return ("<table><tr><th>case</th><th>verdict</th><th>baseline</th><th>recorded</th>"
            "<th>wall s</th><th>what it checks</th></tr>" + "".join(rows) + "</table>")


def page(head: dict, entries: list[dict]) -> str:
    """The whole page: summary line, the overview table, one section a case."""
    title = f"upscale validation, {head['commit']}, {head['date']}"
    summary = (f"{head['cases']} cases: {head['passed']} pass, {head['failed']} fail, "
               f"{head['no_baseline']} without a baseline, {head['stale']} stale baselines, "
               f"{head['raised']} raised; run mode <code>{esc(head['run'])}</code>, "
               f"{head['wall_s']} s. A verdict is this run's <code>pass</code> where the case "
               "ran, else its baseline's.")
    return (f"<!doctype html><html lang=en><head><meta charset=utf-8><title>{esc(title)}</title>"
            f"<style>{CSS}</style></head><body><h1>{esc(title)}</h1><p>{summary}</p>"
            + index_html(entries) + "\n".join(case_html(e) for e in entries)
            + "</body></html>\n")


def _md_row(e: dict) -> str:
    _, text = verdict(e)
    b = e["baseline"]
    prov = f"{b['provenance']['commit']}, {str(b['provenance']['date'])[:10]}" if b else "none"
    wall = (e["run"] or {}).get("wall_s") or (b or {}).get("provenance", {}).get("wall_s")
    st = "stale" if stale_text(e) else ""
    src = e["run"]["status"] if e["run"] else ("baseline" if b else "")
    return (f"| `{e['name']}` | {text} | {src} | {st} | {prov} | "
            f"{fmt(wall) if wall is not None else ''} | {e['summary'].replace('|', '/')} |")


HEADER = ("| case | verdict | from | stale | baseline (commit, date) | wall s | what it checks |\n"
          "| --- | --- | --- | --- | --- | --- | --- |")


def markdown(head: dict, entries: list[dict]) -> str:
    lines = [f"# Validation report, {head['commit']}, {head['date']}", "",
             f"Run mode `{head['run']}`: {head['cases']} cases, {head['passed']} pass, "
             f"{head['failed']} fail, {head['no_baseline']} without a baseline, "
             f"{head['stale']} stale, {head['raised']} raised, {head['wall_s']} s.", "", HEADER]
    return "\n".join(lines + [_md_row(e) for e in entries]) + "\n"


def readme(entries: list[dict]) -> str:
    """``validation/README.md``: how to run the cases and the baselines' verdicts."""
    lines = ["# Validation", "",
             "Generated by `python -m validation report` from `validation/baselines/`; do not "
             "edit by hand.", "",
             "Every case: `python -m validation --list`; one case: `python -m validation CASE "
             "[--quick]` (its plots and JSON in `validation/out/CASE/`); record its figures as "
             "the baseline: `python -m validation CASE --record`; every case on one page: "
             "`python -m validation report [--run none|quick|full]` "
             "(`validation/out/report/report.html`).", "",
             "A verdict below is the baseline's `pass` (the run it records); *stale* means a "
             "file the case imports changed in git after the baseline's commit.", "", HEADER]
    return "\n".join(lines + [_md_row(e) for e in entries]) + "\n"
