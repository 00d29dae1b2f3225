"""``cogail report``: one self-contained HTML page about a run directory.

The page holds the run's configuration (``config.json``, fields that differ from the defaults in bold),
``run_info.json`` and ``speed.json``, learning curves read from the TensorBoard event files in
``tb/seed_*/`` (losses, discriminator accuracy, episode success over env steps, one line per seed), the
evaluation tables (``results.md`` / ``results.json``) with success per checkpoint, and every figure
(``*.png``) and video (``*.gif``, ``*.mp4``) found in the run directory. Images and videos are embedded
base64, so the file can be mailed or committed on its own.

The event files are parsed here (TFRecord framing + ``tensorboardX``'s ``Event`` protobuf), so neither
TensorFlow nor TensorBoard is needed.
"""
from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
import os
import re
import struct
from pathlib import Path

import numpy as np

MEDIA = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".jpeg": "image/jpeg",
         ".svg": "image/svg+xml", ".mp4": "video/mp4", ".webm": "video/webm"}
MAX_MEDIA_BYTES = 40 * 1024 * 1024  # larger files are linked, not embedded
SKIP_DIRS = {"checkpoints", "tb", "__pycache__"}


# ----------------------------------------------------------------------------------------------- events
def read_event_file(path: str | os.PathLike) -> dict[str, dict[int, tuple[float, float]]]:
    """Scalars of one TensorBoard event file: ``{tag: {step: (wall_time, value)}}``.

    TFRecord framing: uint64 length, uint32 masked CRC of the length, payload, uint32 masked CRC of the
    payload. A truncated or corrupt tail (a run killed while writing) ends the read quietly.
    """
    from tensorboardX.proto import event_pb2
    from tensorboardX.record_writer import masked_crc32c

    out: dict[str, dict[int, tuple[float, float]]] = {}
    data = Path(path).read_bytes()
    i = 0
    while i + 12 <= len(data):
        header = data[i:i + 8]
        (n,) = struct.unpack("<Q", header)
        (crc,) = struct.unpack("<I", data[i + 8:i + 12])
        if crc != masked_crc32c(header) or i + 12 + n + 4 > len(data):
            break
        ev = event_pb2.Event()
        try:
            ev.ParseFromString(data[i + 12:i + 12 + n])
        except Exception:  # noqa: BLE001 - a damaged record: keep what was read
            break
        i += 12 + n + 4
        if not ev.HasField("summary"):
            continue
        for v in ev.summary.value:
            if v.HasField("simple_value"):
                x = float(v.simple_value)
            elif v.HasField("tensor") and (v.tensor.float_val or v.tensor.double_val):
                x = float((list(v.tensor.float_val) or list(v.tensor.double_val))[0])
            elif v.HasField("tensor") and v.tensor.tensor_content:
                x = float(np.frombuffer(v.tensor.tensor_content, np.float32)[0])
            else:
                continue
            out.setdefault(v.tag, {})[int(ev.step)] = (float(ev.wall_time), x)
    return out


def read_scalars(tb_dir: str | os.PathLike) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """``{seed: {tag: (steps, values)}}`` from ``tb_dir/seed_<s>/events.*`` (several files per seed, e.g. after
    a resume, are merged; for a step logged twice the later write wins)."""
    tb_dir = Path(tb_dir)
    result = {}
    if not tb_dir.is_dir():
        return result
    for d in sorted(p for p in tb_dir.iterdir() if p.is_dir()):
        seed = d.name[5:] if d.name.startswith("seed_") else d.name
        merged: dict[str, dict[int, tuple[float, float]]] = {}
        for f in sorted(d.glob("events.out.tfevents.*")):
            for tag, pts in read_event_file(f).items():
                m = merged.setdefault(tag, {})
                for step, (wt, x) in pts.items():
                    if step not in m or wt >= m[step][0]:
                        m[step] = (wt, x)
        if merged:
            result[seed] = {tag: (np.array(sorted(m)), np.array([m[s][1] for s in sorted(m)]))
                            for tag, m in merged.items()}
    return dict(sorted(result.items(), key=lambda kv: (not kv[0].isdigit(), int(kv[0]) if kv[0].isdigit() else 0,
                                                        kv[0])))


# ----------------------------------------------------------------------------------------------- plots
GROUPS = (
    ("Episode success (training rollouts)", lambda t: "success" in t),
    ("Discriminator", lambda t: t.startswith("disc")),
    ("Losses", lambda t: "loss" in t),
    ("Other training diagnostics", lambda t: t not in ("nonfinite",)),
)


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def _grid(n: int, ncols: int = 3):
    from matplotlib.figure import Figure

    cols = min(ncols, n)
    rows = (n + cols - 1) // cols
    fig = Figure(figsize=(4.2 * cols, 3.0 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols)).reshape(-1)
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes


SMOOTH_ABOVE = 60  # points per curve above which an exponential moving average is drawn over the raw values


def _ema(x: np.ndarray, span: float = 0.05) -> np.ndarray:
    """Bias-corrected exponential moving average over ~``span`` of the curve's length."""
    alpha = min(1.0, 2.0 / (max(span * len(x), 1.0) + 1.0))
    out, m, w = np.empty(len(x)), 0.0, 0.0
    for i, v in enumerate(np.asarray(x, float)):
        m, w = (1 - alpha) * m + alpha * v, (1 - alpha) * w + alpha
        out[i] = m / w
    return out


def learning_curve_figures(scalars) -> list[tuple[str, bytes]]:
    """One figure per group of tags; one panel per tag; one line per seed (smoothed, over the faint raw values,
    for long runs); x = env steps."""
    tags = sorted({t for per_seed in scalars.values() for t in per_seed})
    short = {t: t.split("/", 1)[-1] for t in tags}
    figures, used = [], set()
    for title, pick in GROUPS:
        chosen = [t for t in tags if t not in used and pick(short[t])]
        if not chosen:
            continue
        used.update(chosen)
        fig, axes = _grid(len(chosen))
        for ax, tag in zip(axes, chosen):
            for seed, per_seed in scalars.items():
                if tag in per_seed:
                    steps, vals = per_seed[tag]
                    if len(vals) > SMOOTH_ABOVE:  # noisy long runs: faint raw values + a moving average
                        (line,) = ax.plot(steps, vals, lw=0.6, alpha=0.25)
                        ax.plot(steps, _ema(vals), lw=1.2, color=line.get_color(), label=f"seed {seed}")
                    else:
                        ax.plot(steps, vals, lw=1.0, label=f"seed {seed}")
            ax.set_title(short[tag], fontsize=10)
            ax.set_xlabel("env steps (per seed)", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=7)
        figures.append((title, _png(fig)))
    return figures


def eval_curve_figure(res: dict, steps_per_update: int | None) -> bytes | None:
    curves, ckpts = res.get("curves") or {}, res.get("checkpoints") or []
    titles = {"replay_success": "test replay success", "validation_replay_success": "validation replay success",
              "interpolation_success": "interpolation success"}
    names = [k for k in titles if k in curves]
    if not names or not ckpts:
        return None
    scale = steps_per_update or 1
    x = np.asarray(ckpts, float) * scale
    fig, axes = _grid(len(names), 3)
    seeds = [str(s) for s in res.get("seeds", [])]
    sel = (res.get("selected") or {}).get("checkpoint")
    pp = res.get("paper_protocol") or {}
    for ax, name in zip(axes, names):
        for i, ys in enumerate(curves[name]):
            if len(ys) == len(x):
                ax.plot(x, 100 * np.asarray(ys, float), marker="o", ms=2.5, lw=1.0,
                        label=f"seed {seeds[i] if i < len(seeds) else i}")
        if len(curves[name]) and all(len(ys) == len(x) for ys in curves[name]):
            ax.plot(x, 100 * np.mean(np.asarray(curves[name], float), 0), color="k", lw=1.8, label="mean")
        if sel is not None:
            ax.axvline(sel * scale, color="tab:green", ls="--", lw=1.0, label="selected on validation")
        col = {"replay_success": "replay", "interpolation_success": "interpolation"}.get(name)
        if col in pp:
            ax.axvline(pp[col]["checkpoint"] * scale, color="tab:red", ls=":", lw=1.2, label="paper protocol")
        ax.set_title(titles[name] + " (%) per checkpoint", fontsize=10)
        ax.set_xlabel("env steps (per seed)" if steps_per_update else "update", fontsize=8)
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    return _png(fig)


def _headline(res: dict) -> list[tuple[str, str]]:
    """(label, "mean +- std") of the reported figures: selected on validation and the paper protocol (results
    made before the protocol: the per-seed best they reported)."""
    f = lambda d: f"{100 * d['mean']:.1f} &plusmn; {100 * d.get('std', 0):.1f} %"  # noqa: E731
    out = []
    if isinstance(res.get("paper_protocol"), dict):
        for col in ("replay", "interpolation"):
            if isinstance(res.get("selected"), dict) and col in res["selected"]:
                out.append((f"{col}, selected on validation (ckpt {res['selected']['checkpoint']})",
                            f(res["selected"][col])))
            pp = res["paper_protocol"].get(col)
            if isinstance(pp, dict):
                out.append((f"{col}, paper protocol (ckpt {pp.get('checkpoint')})", f(pp)))
        cp = res.get("coplay")
        if isinstance(cp, dict) and isinstance((cp.get("learned") or {}).get("selected"), dict):
            sel = cp["learned"]["selected"]  # closed-loop co-play with the scripted human and with the proxy
            for name in ("scripted", "proxy"):
                if isinstance(sel["success"].get(name), dict):
                    out.append((f"co-play with the {name} human, selected (ckpt {sel['checkpoint']})",
                                f(sel["success"][name])))
        return out
    for k in ("replay_success", "interpolation_success"):
        if isinstance(res.get(k), dict) and "mean" in res[k]:
            out.append((k.replace("_", " ") + " (best ckpt per seed)", f(res[k])))
    return out


# ----------------------------------------------------------------------------------------------- HTML
def _inline(text: str) -> str:
    t = html.escape(text)
    t = re.sub(r"`([^`]+)`", r"<code>\1</code>", t)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", t)


def markdown_to_html(md: str) -> str:
    """The Markdown subset the evaluation writes: headings, pipe tables, lists, paragraphs."""
    out, para, lines, i = [], [], md.splitlines(), 0

    def flush():
        if para:
            out.append(f"<p>{_inline(' '.join(para))}</p>")
            para.clear()

    while i < len(lines):
        line = lines[i].rstrip()
        if not line.strip():
            flush()
        elif line.startswith("#"):
            flush()
            level = min(len(line) - len(line.lstrip("#")) + 2, 6)  # the page's own h1/h2 come first
            out.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
        elif line.lstrip().startswith("|"):
            flush()
            rows = []
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                rows.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            i -= 1
            body = [r for r in rows[1:] if not all(re.fullmatch(r":?-{3,}:?", c) for c in r)]
            t = ["<table>", "<tr>" + "".join(f"<th>{_inline(c)}</th>" for c in rows[0]) + "</tr>"]
            t += ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body]
            out.append("\n".join(t + ["</table>"]))
        elif re.match(r"\s*[-*] ", line):
            flush()
            items = []
            while i < len(lines) and re.match(r"\s*[-*] ", lines[i]):
                item = re.sub(r"^\s*[-*] ", "", lines[i])
                items.append(f"<li>{_inline(item)}</li>")
                i += 1
            i -= 1
            out.append("<ul>" + "".join(items) + "</ul>")
        else:
            para.append(line.strip())
        i += 1
    flush()
    return "\n".join(out)


def _table(rows, header=("field", "value")) -> str:
    t = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for r in rows:
        t.append("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>")
    return "\n".join(t + ["</table>"])


def _fmt(v) -> str:
    if isinstance(v, float):
        return html.escape(f"{v:.6g}")
    if isinstance(v, (dict, list)):
        return f"<code>{html.escape(json.dumps(v))}</code>"
    return html.escape(str(v))


def _flatten(d: dict, prefix: str = "") -> list[tuple[str, object]]:
    rows = []
    for k, v in d.items():
        if isinstance(v, dict) and v:
            rows += _flatten(v, f"{prefix}{k}.")
        else:
            rows.append((f"{prefix}{k}", v))
    return rows


def _img(data: bytes, mime: str, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:{mime};base64,{base64.b64encode(data).decode()}">'


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _media_files(run_dir: Path, out: Path | None) -> list[Path]:
    found = []
    for root, dirs, files in os.walk(run_dir):
        depth = len(Path(root).relative_to(run_dir).parts)
        dirs[:] = sorted(d for d in dirs if d not in SKIP_DIRS and not d.startswith(".") and depth < 2)
        for f in sorted(files):
            p = Path(root) / f
            if p.suffix.lower() in MEDIA and (out is None or p.resolve() != out.resolve()):
                found.append(p)
    return found


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1200px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em} th,td{border:1px solid #ccc;padding:.25em .6em;
text-align:left;vertical-align:top} th{background:#f3f3f3} code{font-size:.9em;word-break:break-all}
img,video{max-width:100%;border:1px solid #eee;margin:.4em 0} figure{margin:1em 0}
figcaption{color:#555;font-size:.9em} .note{background:#fff8e1;border-left:4px solid #f0b400;padding:.5em .8em}
.muted{color:#777;font-size:.85em} .cards{display:flex;flex-wrap:wrap;gap:.8em}
.card{border:1px solid #ddd;border-radius:6px;padding:.5em .9em;min-width:9em}
.card b{display:block;font-size:1.3em}
"""


def build_report(run_dir: str | os.PathLike, out: str | os.PathLike | None = None) -> Path:
    """Write the HTML report of ``run_dir`` (default ``run_dir/report.html``); returns its path."""
    from ..algo.config import TrainConfig

    run_dir = Path(run_dir)
    if not run_dir.is_dir() or not ((run_dir / "config.json").exists() or (run_dir / "tb").is_dir()):
        from .runs import RunError

        raise RunError(f"{run_dir} is not a run directory (no config.json, no tb/): pass the --run of a training run")
    out = Path(out) if out else run_dir / "report.html"
    cfg = _read_json(run_dir / "config.json")
    info = _read_json(run_dir / "run_info.json")
    speed = _read_json(run_dir / "speed.json")
    res = _read_json(run_dir / "results.json")
    res_md = (run_dir / "results.md").read_text() if (run_dir / "results.md").exists() else None
    cfg = cfg if isinstance(cfg, dict) else None
    spu = None
    if cfg:
        try:
            spu = int(cfg["num_envs"]) * int(cfg["unroll_length"])
        except (KeyError, TypeError, ValueError):
            spu = None
    task = (cfg or {}).get("task") or (res or {}).get("task") or "?"
    method = (cfg or {}).get("method") or (res or {}).get("method") or "?"
    seeds = (cfg or {}).get("seeds") or (res or {}).get("seeds") or []

    body = [f"<h1>{html.escape(str(method))} on {html.escape(str(task))}</h1>",
            f'<p class="muted">run directory <code>{html.escape(str(run_dir))}</code>; report written '
            f'{_dt.datetime.now().strftime("%Y-%m-%d %H:%M")} by <code>cogail report</code></p>']

    # --- summary cards
    cards = [("seeds", ", ".join(map(str, seeds)) or "?")]
    ckpt_dir = run_dir / "checkpoints"
    ckpts = sorted(int(p.name) for p in ckpt_dir.iterdir() if p.is_dir() and p.name.isdigit()) if ckpt_dir.is_dir() else []
    if ckpts:
        cards.append(("last checkpoint (update)", str(ckpts[-1])))
    if cfg and spu:
        cards.append(("env steps per seed", f"{int(cfg.get('total_steps', 0)):,}"))
    if isinstance(speed, dict) and "env_steps_per_s" in speed:
        cards.append(("env steps / s (all seeds)", f"{speed['env_steps_per_s']:,.0f}"))
    if isinstance(res, dict):
        cards += _headline(res)
    body.append('<div class="cards">' + "".join(f'<div class="card"><b>{v}</b>{html.escape(k)}</div>'
                                                for k, v in cards) + "</div>")

    # --- evaluation
    body.append("<h2>Evaluation</h2>")
    if res is None and res_md is None:
        body.append(f'<p class="note">This run has not been evaluated yet: run <code>cogail eval --run '
                    f'{html.escape(str(run_dir))}</code>, then <code>cogail report</code> again.</p>')
    else:
        if res_md:
            body.append(markdown_to_html(res_md))
        elif isinstance(res, dict):
            body.append(_table([(html.escape(k), v) for k, v in _headline(res)], ("figure", "mean &plusmn; std")))
        if isinstance(res, dict):
            png = eval_curve_figure(res, spu)
            if png:
                body.append(f"<figure>{_img(png, 'image/png', 'evaluation per checkpoint')}<figcaption>Success of "
                            f"every evaluated checkpoint, one line per seed and their mean; dashed: the checkpoint "
                            f"selected on validation, dotted: the paper protocol's.</figcaption></figure>")

    # --- learning curves
    body.append("<h2>Learning curves</h2>")
    scalars = read_scalars(run_dir / "tb")
    if not scalars:
        body.append(f'<p class="note">No TensorBoard scalars found in <code>{html.escape(str(run_dir / "tb"))}'
                    f"</code>: the run has not logged an update yet.</p>")
    else:
        n = {s: max(len(v[0]) for v in per.values()) for s, per in scalars.items()}
        body.append(f'<p class="muted">From <code>tb/seed_*/</code>: {len(scalars)} seed(s), up to '
                    f"{max(n.values())} logged updates each; x is env steps per seed.</p>")
        for title, png in learning_curve_figures(scalars):
            body.append(f"<h3>{html.escape(title)}</h3><figure>{_img(png, 'image/png', title)}</figure>")

    # --- figures and videos
    media = _media_files(run_dir, out)
    imgs = [p for p in media if MEDIA[p.suffix.lower()].startswith("image/")]
    vids = [p for p in media if MEDIA[p.suffix.lower()].startswith("video/")]
    for title, files in (("Figures", imgs), ("Videos", vids)):
        body.append(f"<h2>{title}</h2>")
        if not files:
            body.append(f'<p class="muted">No {title.lower()} in the run directory'
                        + (" (run <code>cogail eval</code> to make them)." if title == "Figures"
                           else " (make some with <code>cogail video --run DIR</code>).") + "</p>")
        for p in files:
            rel = html.escape(str(p.relative_to(run_dir)))
            size = p.stat().st_size
            mime = MEDIA[p.suffix.lower()]
            if size > MAX_MEDIA_BYTES:
                body.append(f'<p class="note"><code>{rel}</code> ({size / 2**20:.0f} MB) is too large to embed; '
                            f"open it next to this page.</p>")
                continue
            b64 = base64.b64encode(p.read_bytes()).decode()
            el = (f'<video controls loop muted src="data:{mime};base64,{b64}"></video>' if mime.startswith("video/")
                  else f'<img alt="{rel}" src="data:{mime};base64,{b64}">')
            body.append(f"<figure>{el}<figcaption><code>{rel}</code></figcaption></figure>")

    # --- configuration and run info
    body.append("<h2>Configuration</h2>")
    if cfg is None:
        body.append('<p class="note">No readable config.json in the run directory.</p>')
    else:
        defaults = json.loads(TrainConfig().to_json())
        rows = []
        for k, v in cfg.items():
            changed = k in defaults and defaults[k] != v
            val = _fmt(v)
            rows.append((f"<b>{html.escape(k)}</b>" if changed else html.escape(k), f"<b>{val}</b>" if changed else val,
                         _fmt(defaults[k]) if k in defaults else "<i>not a current field</i>"))
        body.append('<p class="muted">config.json; fields that differ from the defaults are in bold.</p>')
        body.append(_table(rows, ("field", "value", "default")))
    for name, obj in (("Run information (run_info.json)", info), ("Speed (speed.json)", speed)):
        if isinstance(obj, dict):
            body.append(f"<h2>{name}</h2>")
            body.append(_table([(html.escape(k), _fmt(v)) for k, v in _flatten(obj)]))

    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>cogail report: {html.escape(str(method))} on {html.escape(str(task))}</title>"
            f"<style>{CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, out)
    return out


__all__ = ["build_report", "read_scalars", "read_event_file", "markdown_to_html"]
