#!/usr/bin/env python3
"""The reports of scripts/remote-bench (Python standard library only).

    remote_bench_report.py line SUMMARY.json
        one line for the terminal: "14.2 fps (3.04 MB/frame, 0/72 bad)"
    remote_bench_report.py aggregate
        OUT/runs.tsv and every run's summary.json into OUT/results.md, results.csv and
        per_frame.csv

`aggregate` reads what remote-bench exports: RB_OUT (the output folder), RB_MAIN_CODEC,
RB_CMDLINE, RB_DATE, RB_NPROC, RB_CPU, RB_COMMIT, RB_ELAPSED, RB_FRAMES, RB_CHECK and
RB_LINK_NOTE (may be empty).
"""
import csv
import json
import os
import statistics
import sys


def summary_line(path):
    """fps, MB per frame, bad pixels and incidents of one run's summary.json."""
    with open(path) as f:
        s = json.load(f)
    bad = (f"{s['frames_with_bad_pixels']}/{s['checked_frames']} bad"
           if s.get("checked_frames") else "unchecked")
    inc = len(s.get("incidents") or [])
    fps = s.get("display_fps")
    rate = "– fps" if fps is None else f"{fps:.1f} fps"
    mb = s.get("bytes_per_frame")
    size = "no frame delivered" if mb is None else f"{mb / 1e6:.2f} MB/frame"
    print(f"{rate} ({size}, {bad}" + (f", {inc} incident(s)" if inc else "") + ")")


def aggregate():
    """Writes results.md, results.csv and per_frame.csv into $RB_OUT."""
    out = os.environ["RB_OUT"]
    main_codec = os.environ["RB_MAIN_CODEC"]
    LINK_ORDER = {"loopback": 0, "gigabit": 1}


    def transfer_key(t):
        order = {"full": 0, "depth-limited": 1, "difference": 2, "reprojection": 3}
        base, _, arg = t.partition(":")
        return (order.get(base, 9), int(arg) if arg.isdigit() else -1)


    def size_key(s):
        w, h = s.split("x")
        return (int(w) * int(h), int(w))


    runs = []
    with open(os.path.join(out, "runs.tsv"), newline="") as f:
        for r in csv.DictReader(f, delimiter="\t"):
            r["summary"] = None
            if r["status"] == "ok":
                try:
                    with open(os.path.join(out, r["dir"], "summary.json")) as g:
                        r["summary"] = json.load(g)
                except (OSError, ValueError) as e:
                    r["status"], r["note"] = "failed", f"summary.json unreadable: {e}"
            runs.append(r)

    scene_order = list(dict.fromkeys(r["scene"] for r in runs))


    def sort_key(r):
        return (scene_order.index(r["scene"]), size_key(r["size"]), transfer_key(r["transfer"]),
                LINK_ORDER.get(r["link"], 9), r["codec"])


    def find(scene, size, transfer, codec, link=None):
        """The run for this combination (first link in LINK_ORDER when link is None)."""
        c = [r for r in runs if (r["scene"], r["size"], r["transfer"], r["codec"]) ==
             (scene, size, transfer, codec) and (link is None or r["link"] == link)]
        c.sort(key=lambda r: (r["status"] != "ok", LINK_ORDER.get(r["link"], 9)))
        return c[0] if c else None


    def f1(x):
        return "–" if x is None else f"{x:.1f}"


    def mb(x):
        return "–" if x is None else f"{x / 1e6:.3f}"


    def pct(x, digits=1):
        return "–" if x is None else f"{100 * x:.{digits}f}"


    def fps(s):
        """Display fps needs two delivered frames at least (the summary has none otherwise)."""
        return f1(s.get("display_fps"))


    def bad(s):
        if not s.get("checked_frames"):
            return "not checked"
        return f"{s['frames_with_bad_pixels']}/{s['checked_frames']} (max {s['max_bad_pixels']})"


    def table(header, rows):
        lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
        lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
        return "\n".join(lines)


    md = []
    md.append("# strata remote rendering benchmark (seed 000, Tables A.1/A.2, Figures 6.1–6.3)\n")
    md.append(f"`{os.environ['RB_CMDLINE']}` — {os.environ['RB_DATE']}, nproc {os.environ['RB_NPROC']}, "
              f"CPU {os.environ['RB_CPU']}, git {os.environ['RB_COMMIT']}\n")
    n_ok = sum(r["status"] == "ok" for r in runs)
    md.append(f"{len(runs)} runs ({n_ok} ok, {len(runs) - n_ok} failed), {os.environ['RB_FRAMES']} frames each, "
              f"exactness check {'on' if os.environ['RB_CHECK'] == '1' else 'off'}, "
              f"{int(os.environ['RB_ELAPSED']) // 60} min {int(os.environ['RB_ELAPSED']) % 60} s in all. "
              "One node renders the whole scene (rotating 5°/frame, alpha 0.5) and the display merges "
              "and resolves. MB = 10^6 bytes. *Seed layout* = the seed's uncompressed linked list, "
              "4 B per pixel + 12 B per fragment. *% of 16 B·fragments* = encoded bytes against 16 B "
              "per rendered fragment. Times are medians over delivered frames; fps is from the first delivered frame to the last.")
    if os.environ.get("RB_LINK_NOTE"):
        md.append(f"\nGigabit link: {os.environ['RB_LINK_NOTE'].strip()}")
    md.append("")

    failed = [r for r in runs if r["status"] != "ok"]
    if failed:
        md.append("## Failed runs\n")
        md.append(table(["#", "link", "scene", "size", "transfer", "codec", "why"],
                        [[r["index"], r["link"], r["scene"], r["size"], r["transfer"], r["codec"],
                          r["note"].replace("|", "\\|")] for r in failed]))
        md.append("")

    main = sorted((r for r in runs if r["codec"] == main_codec), key=sort_key)
    combos = list(dict.fromkeys((r["scene"], r["size"], r["transfer"]) for r in main))

    # ---- Table A.1
    md.append(f"## Table A.1 — bytes per frame ({main_codec})\n")
    rows, notes = [], []
    for sc, size, t in combos:
        r = find(sc, size, t, main_codec)
        if r["summary"] is None:
            rows.append([sc, size, t] + ["FAILED"] * 7)
            continue
        s = r["summary"]
        # Bad pixels: the worst over the links (they should agree).
        worst = max((x for x in runs if x["summary"] and (x["scene"], x["size"], x["transfer"], x["codec"])
                     == (sc, size, t, main_codec)), key=lambda x: (x["summary"]["frames_with_bad_pixels"],
                                                                   x["summary"]["max_bad_pixels"]))
        for x in runs:
            if (x is not r and x["summary"] and (x["scene"], x["size"], x["transfer"], x["codec"]) ==
                    (sc, size, t, main_codec)):
                d = abs(x["summary"]["bytes_per_frame"] / s["bytes_per_frame"] - 1) if s["bytes_per_frame"] else 0
                if d > 0.001:
                    notes.append(f"{sc} {size} {t}: {x['link']} sent {100 * d:.2f} % different bytes than {r['link']}")
        rows.append([sc, size, t, mb(s["bytes_per_frame"]), mb(s["raw_bytes_per_frame"]),
                     pct(s["bytes_per_frame"] / s["raw_bytes_per_frame"]) if s["raw_bytes_per_frame"] else "–",
                     pct(s["bytes_vs_16n"]), pct(s["fragments_sent_share"]),
                     pct(s["fragments_sent_share_after_first"]) if s.get("frames", 0) >= 2 else "–",
                     bad(worst["summary"])])
    md.append(table(["scene", "size", "transfer", "MB/frame encoded", "MB/frame list layout",
                     "encoded % of seed", "% of 16 B·fragments", "fragments sent %",
                     "sent % after frame 0", "bad-pixel frames (max)"], rows))
    md.append("\nBytes from the first link that ran each combination; bad pixels are the worst over the links.")
    for n in notes:
        md.append(f"\nNote: {n}")
    md.append("")

    # ---- codec comparison
    cmp = [r for r in runs if r["codec"] != main_codec]
    if cmp:
        cmp_keys = list(dict.fromkeys((r["scene"], r["size"], r["transfer"], r["link"])
                                      for r in sorted(cmp, key=sort_key)))
        codecs = list(dict.fromkeys(r["codec"] for r in runs if r["codec"] != main_codec))
        order = ["raw", "lz4", "zstd", "deep-lz4", "deep-zstd", "deep-huff"]
        codecs = sorted(set(codecs) | {main_codec}, key=lambda c: (order.index(c.split(":")[0]) if c.split(":")[0] in order else 9, c))
        link = cmp_keys[0][3]
        md.append(f"## Codecs — bytes per frame at {cmp_keys[0][1]} (Figure 6.1's LZ4 saving; {link} link)\n")
        rows = []
        for sc, size, t, link in cmp_keys:
            lz = find(sc, size, t, "lz4", link)
            lz_b = lz["summary"]["bytes_per_frame"] if lz and lz["summary"] else None
            raw = find(sc, size, t, "raw", link)
            raw_b = raw["summary"]["bytes_per_frame"] if raw and raw["summary"] else None
            for c in codecs:
                r = find(sc, size, t, c, link)
                if r is None:
                    continue
                if r["summary"] is None:
                    rows.append([sc, t, c] + ["FAILED"] * 7)
                    continue
                s = r["summary"]
                b = s["bytes_per_frame"]
                rows.append([sc, t, c, mb(b), pct(s["bytes_vs_16n"]),
                             pct(b / lz_b) if lz_b else "–", pct(b / raw_b) if raw_b else "–",
                             f1(s["encode_ms"]), f1(s["decode_ms"]), fps(s)])
        md.append(table(["scene", "transfer", "codec", "MB/frame", "% of 16 B·fragments", "% of lz4",
                         "% of raw", "node encode ms", "decode ms", f"fps ({link})"], rows))
        md.append("")

    # ---- Table A.2
    md.append(f"## Table A.2 — frame rate and per-stage times ({main_codec})\n")
    rows = []
    for r in main:
        s = r["summary"]
        if s is None:
            rows.append([r["scene"], r["size"], r["transfer"], r["link"]] + ["FAILED"] * 10)
            continue
        rows.append([r["scene"], r["size"], r["transfer"], r["link"], fps(s),
                     f1(s["render_ms"]), f1(s["select_ms"]), f1(s["encode_ms"]), f1(s["transfer_ms"]),
                     f1(s["decode_ms"]), f1(s["merge_ms"]), f1(s["resolve_ms"]), f1(s["interval_ms"]),
                     len(s.get("incidents") or [])])
    md.append(table(["scene", "size", "transfer", "link", "display fps", "node render ms",
                     "node select ms", "node encode ms", "transfer ms", "decode ms", "merge ms",
                     "resolve ms", "interval ms", "incidents"], rows))
    md.append("\nNode and display share this machine's cores, so the stages slow each other down; "
              "on separate machines the pipeline's throughput would be its slowest stage's.\n")

    # ---- Figure 6.1
    md.append(f"## Figure 6.1 — bytes saved against the list layout ({main_codec}), mean over scenes\n")
    sizes = sorted({r["size"] for r in main}, key=size_key)
    transfers = sorted({r["transfer"] for r in main}, key=transfer_key)
    rows = []
    for size in sizes:
        row = [size]
        for t in transfers:
            v = [1 - r["summary"]["bytes_per_frame"] / r["summary"]["raw_bytes_per_frame"]
                 for r in main if r["size"] == size and r["transfer"] == t and r["summary"]
                 and r["summary"]["raw_bytes_per_frame"] and r is find(r["scene"], size, t, main_codec)]
            row.append(pct(statistics.mean(v)) if v else "–")
        rows.append(row)
    md.append(table(["size"] + [f"{t} saved %" for t in transfers], rows))
    md.append("")

    # ---- Figure 6.2
    dl = [r for r in main if r["transfer"].startswith("depth-limited:") and r["summary"]
          and r["summary"].get("checked_frames") and r is find(r["scene"], r["size"], r["transfer"], main_codec)]
    md.append("## Figure 6.2 — bad pixels of depth-limited transfers by layer count\n")
    if dl:
        rows = []
        for r in sorted(dl, key=sort_key):
            s = r["summary"]
            w, h = (int(v) for v in r["size"].split("x"))
            per = [p.get("bad_pixels") for p in s.get("per_frame", []) if p.get("bad_pixels") is not None]
            mean_bad = statistics.mean(per) if per else 0
            rows.append([r["scene"], r["size"], r["transfer"].split(":")[1], f"{mean_bad:.1f}",
                         f"{100 * mean_bad / (w * h):.4f}", s["max_bad_pixels"],
                         f"{s['frames_with_bad_pixels']}/{s['checked_frames']}", pct(s["fragments_sent_share"])])
        md.append(table(["scene", "size", "layers", "mean bad pixels/frame", "% of pixels",
                         "max bad pixels", "frames with bad pixels", "fragments sent %"], rows))
        md.append("\nOne point per depth-limited:N in --transfers; add depth-limited:1,depth-limited:2,… "
                  "for the whole curve.")
    else:
        md.append("(no checked depth-limited runs)")
    md.append("")

    # ---- Figure 6.3
    diff = [r for r in main if r["transfer"].startswith(("difference", "reprojection")) and r["summary"]
            and r is find(r["scene"], r["size"], r["transfer"], main_codec)]
    md.append("## Figure 6.3 — fragments sent per frame by difference and reprojection transfers (% of rendered)\n")
    if diff:
        rows = []
        for r in sorted(diff, key=sort_key):
            shares = []
            for p in r["summary"].get("per_frame", []):
                rend = sum(n.get("fragments_rendered", 0) for n in p.get("nodes", []))
                sent = sum(n.get("fragments_sent", 0) for n in p.get("nodes", []))
                if rend:
                    shares.append(sent / rend)
            later = shares[1:]
            rows.append([r["scene"], r["size"], r["transfer"], pct(shares[0]) if shares else "–",
                         pct(min(later)) if later else "–", pct(statistics.median(later)) if later else "–",
                         pct(max(later)) if later else "–",
                         pct(1 - r["summary"]["fragments_sent_share_after_first"]),
                         pct(r["summary"].get("removals_share_after_first", 0.0))])
        md.append(table(["scene", "size", "transfer", "frame 0", "min after 0", "median after 0",
                         "max after 0", "saved after 0 %", "removals after 0 %"], rows))
        md.append("\nReprojection removals are positions in the display's runs (a byte or two each), "
                  "not fragments; the seed counted each as a flagged fragment in its difference list. "
                  "Per-frame values (for plotting) are in per_frame.csv.")
    else:
        md.append("(no difference or reprojection runs)")
    md.append("")

    with open(os.path.join(out, "results.md"), "w") as f:
        f.write("\n".join(md))

    # ---- CSVs
    fields = ["display_fps", "bytes_per_frame", "raw_bytes_per_frame", "bytes_vs_16n",
              "fragments_sent_share", "fragments_sent_share_after_first",
              "removals_share_after_first", "render_ms", "select_ms",
              "encode_ms", "transfer_ms", "decode_ms", "merge_ms", "resolve_ms", "interval_ms",
              "checked_frames", "frames_with_bad_pixels", "max_bad_pixels"]
    with open(os.path.join(out, "results.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["index", "link", "scene", "size", "transfer", "codec", "status", "frames"] + fields
                   + ["incidents", "dir", "note"])
        for r in sorted(runs, key=lambda r: int(r["index"])):
            s = r["summary"] or {}
            w.writerow([r["index"], r["link"], r["scene"], r["size"], r["transfer"], r["codec"],
                        r["status"], s.get("frames", "")] + [s.get(k, "") for k in fields]
                       + [len(s.get("incidents") or []) if s else "", r["dir"], r["note"]])
    with open(os.path.join(out, "per_frame.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["index", "link", "scene", "size", "transfer", "codec", "frame", "bytes", "raw_bytes",
                    "fragments_rendered", "fragments_sent", "render_ms", "select_ms", "encode_ms",
                    "transfer_ms", "decode_ms", "merge_ms", "resolve_ms", "interval_ms", "bad_pixels"])
        for r in sorted(runs, key=lambda r: int(r["index"])):
            for p in (r["summary"] or {}).get("per_frame", []):
                ns = p.get("nodes", [])
                tot = lambda k: sum(n.get(k, 0) or 0 for n in ns)
                mx = lambda k: max((n.get(k, 0) or 0 for n in ns), default="")
                w.writerow([r["index"], r["link"], r["scene"], r["size"], r["transfer"], r["codec"],
                            p.get("frame"), tot("bytes"), tot("raw_bytes"), tot("fragments_rendered"),
                            tot("fragments_sent"), mx("render_ms"), mx("select_ms"), mx("encode_ms"),
                            mx("transfer_ms"), mx("decode_ms"), p.get("merge_ms"), p.get("resolve_ms"),
                            p.get("interval_ms"), p.get("bad_pixels", "")])


def main(argv):
    if len(argv) == 3 and argv[1] == "line":
        summary_line(argv[2])
    elif len(argv) == 2 and argv[1] == "aggregate":
        aggregate()
    else:
        sys.exit(f"usage: {argv[0]} line SUMMARY.json | aggregate")


if __name__ == "__main__":
    main(sys.argv)
