#!/usr/bin/env python3
"""`strata view` in a real browser: headless Chromium driven by Playwright.

Usage: tests/browser/test_view.py [--strata PATH] [--out DIR] [-k NAME]

Starts `strata view` on free ports, opens the page in the system's Chromium (nothing is
downloaded) and checks what a person would: the first frame is the image `strata render` makes of
the same view; dragging orbits the camera, and the camera the page reports renders, pasted into a
scene file, to the very image on the canvas; switching the method and its options gives the
statistics `strata render --stats` reports; bad input of every kind gets an error in the page and
never takes the server down; a killed socket reconnects; pages beyond --max-pages are told why;
in the multi-frame-rate mode, dragging an object moves it on the fast client ahead of a held-back
slow client, deep composition stays exact against the single renderer, and digital composition
shows the seed's artefact while the object is behind the windscreen; in the remote mode, the page
orbits two render nodes' merged frame, which is what `strata render` makes of the view, and shows
a node that dies as held, with its incident.
Screenshots of each state go to --out (default target/browser-tests).

Exit status 0 if every test passed, 1 if one failed. Without Chromium or Playwright it says so and
exits 0, unless STRATA_REQUIRE_TOOLS=1 (CI), where a missing browser is a failure.
"""

import argparse
import base64
import json
import math
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENE = "spheres"
SIZE = (320, 180)


def find_browser():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class Server:
    """A `strata view` process on a free port."""

    def __init__(self, strata, *args, scene=SCENE, listen="127.0.0.1:0"):
        self.proc = subprocess.Popen(
            [strata, "view", scene, "--listen", listen, "-j", "2", *args],
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + 60
        self.url = None
        while time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            if not line:
                break
            m = re.search(r"at (http://127\.0\.0\.1:\d+/)", line)
            if m:
                self.url = m.group(1)
                break
        if self.url is None:
            self.proc.kill()
            raise RuntimeError(f"strata view did not start: {self.proc.stderr.read()}")

    def alive(self):
        return self.proc.poll() is None

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


class Node:
    """A `strata node` process serving some objects of a scene file on a free port."""

    def __init__(self, strata, scene, objects):
        self.proc = subprocess.Popen(
            [strata, "node", "--listen", "127.0.0.1:0", "--scene", str(scene),
             "--objects", objects],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        line = self.proc.stdout.readline()
        m = re.match(r"listening on (\S+)", line)
        if not m:
            self.proc.kill()
            raise RuntimeError(f"strata node did not start: {line!r}")
        self.addr = m.group(1)

    def stop(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)


def scene_source(strata, scene=SCENE):
    """A built-in scene's file."""
    return subprocess.run(
        [strata, "scenes", "--print", scene], check=True, capture_output=True, text=True
    ).stdout


def without_animation(source):
    """A scene file's text without its [animation] table."""
    out, skipping = [], False
    for l in source.splitlines():
        if l.startswith("["):
            skipping = l.strip() == "[animation]"
        if not skipping:
            out.append(l)
    return "\n".join(out) + "\n"


def scene_with_view(strata, view_toml, path, source=None):
    """The built-in scene's file (or `source`) with the page's size and camera pasted in."""
    source = source if source is not None else scene_source(strata)
    lines = source.splitlines()
    first_table = next(i for i, l in enumerate(lines) if l.startswith("["))
    preamble = [l for l in lines[:first_table] if not re.match(r"(width|height)\s*=", l)]
    tables, skipping = [], False
    for l in lines[first_table:]:
        if l.startswith("["):
            skipping = l.strip() == "[camera]"
        if not skipping:
            tables.append(l)
    size, camera = view_toml.split("[camera]", 1)
    text = "\n".join([size.strip(), *preamble, "[camera]" + camera, *tables]) + "\n"
    Path(path).write_text(text)
    return path


def render(strata, scene_file, out_png, *method_args):
    stats = str(out_png) + ".json"
    subprocess.run(
        [strata, "render", str(scene_file), "--out", str(out_png), "--stats", stats, "-j", "2",
         *method_args],
        check=True,
        capture_output=True,
    )
    return json.loads(Path(stats).read_text())


COMPARE_JS = """async ([b64, x0]) => {
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  const bitmap = await createImageBitmap(new Blob([bytes], {type: 'image/png'}),
                                         {colorSpaceConversion: 'none', premultiplyAlpha: 'none'});
  const view = document.getElementById('frame');
  if (x0 + bitmap.width > view.width || bitmap.height !== view.height)
    return {size: [view.width, view.height], expected: [bitmap.width, bitmap.height], x0};
  const ref = new OffscreenCanvas(bitmap.width, bitmap.height).getContext('2d');
  ref.drawImage(bitmap, 0, 0);
  const a = ref.getImageData(0, 0, bitmap.width, bitmap.height).data;
  const b = view.getContext('2d').getImageData(x0, 0, bitmap.width, bitmap.height).data;
  let differing = 0, maxDiff = 0;
  for (let i = 0; i < a.length; i += 4) {
    let d = 0;
    for (let c = 0; c < 3; c++) d = Math.max(d, Math.abs(a[i + c] - b[i + c]));
    if (d > 0) differing++;
    maxDiff = Math.max(maxDiff, d);
  }
  return {differing, maxDiff, pixels: a.length / 4};
}"""


class Suite:
    def __init__(self, strata, out, browser_path):
        self.strata = strata
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix="strata-view-"))
        self.browser_path = browser_path

    # ---- helpers --------------------------------------------------------------------------
    def open_page(self, url, size=SIZE):
        page = self.browser.new_page(viewport={"width": 1200, "height": 700})
        page.on("pageerror", lambda e: self.page_errors.append(str(e)))
        page.goto(f"{url}?size={size[0]}x{size[1]}")
        self.wait_frame(page, after=0)
        return page

    def wait_frame(self, page, after, timeout=30000):
        """Waits for a frame answering a request newer than `after`; returns its header."""
        from playwright.sync_api import TimeoutError as Timeout

        try:
            page.wait_for_function(
                "(after) => window.strataView.frame && window.strataView.frame.id > after"
                " && window.strataView.frame.id === window.strataView.lastSentId",
                arg=after,
                timeout=timeout,
            )
        except Timeout:
            errors = page.evaluate("window.strataView.errors")
            raise AssertionError(f"no frame after request {after}; errors in the page: {errors}")
        return page.evaluate("window.strataView.frame")

    def last_id(self, page):
        return page.evaluate("window.strataView.frame ? window.strataView.frame.id : 0")

    def drag(self, page, dx, dy):
        """Drags across the canvas from its centre; returns the centre."""
        box = page.locator("#frame").bounding_box()
        x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(x, y)
        page.mouse.down()
        for i in range(1, 11):
            page.mouse.move(x + dx * i / 10, y + dy * i / 10)
        page.mouse.up()
        return x, y

    def shot(self, page, name):
        page.screenshot(path=str(self.out / f"{name}.png"))

    def compare_with_render(self, page, header, name, *method_args, x0=0, source=None):
        scene = scene_with_view(self.strata, header["camera_toml"], self.tmp / f"{name}.toml",
                                source)
        png = self.tmp / f"{name}.png"
        stats = render(self.strata, scene, png, *method_args)
        self.compare_with_png(page, png, name, x0)
        return stats

    def compare_with_png(self, page, png, name, x0=0):
        diff = page.evaluate(COMPARE_JS, [base64.b64encode(Path(png).read_bytes()).decode(), x0])
        assert diff.get("differing") == 0, f"{name}: canvas differs from {png}: {diff}"

    # ---- tests ----------------------------------------------------------------------------
    def test_first_frame_is_what_render_makes(self):
        page = self.open_page(self.server.url)
        header = page.evaluate("window.strataView.frame")
        hello = page.evaluate("window.strataView.hello")
        assert header["stats"]["width"] == SIZE[0] and header["stats"]["height"] == SIZE[1]
        assert header["camera"] == hello["camera"], (header["camera"], hello["camera"])
        self.compare_with_render(page, header, "first")
        assert page.locator("#stats").inner_text().count("fragments") >= 2
        self.shot(page, "01-first-frame")
        page.close()

    def test_dragging_orbits_the_camera(self):
        page = self.open_page(self.server.url)
        before = page.evaluate("window.strataView.frame")
        x, y = self.drag(page, 120, 40)
        after = self.wait_frame(page, before["id"])
        c0, c1 = before["camera"], after["camera"]
        assert c1["eye"] != c0["eye"], "the eye did not move"
        assert c1["target"] == c0["target"], "orbiting moved the target"
        d0 = math.dist(c0["eye"], c0["target"])
        d1 = math.dist(c1["eye"], c1["target"])
        assert abs(d0 - d1) < 1e-4 * d0, f"orbiting changed the distance {d0} -> {d1}"
        assert page.locator("#camera").input_value() == after["camera_toml"]
        self.compare_with_render(page, after, "orbited")
        self.shot(page, "02-orbited")
        # Wheel zoom brings the eye closer to the target.
        page.mouse.move(x, y)
        page.mouse.wheel(0, -400)
        zoomed = self.wait_frame(page, after["id"])
        assert math.dist(zoomed["camera"]["eye"], zoomed["camera"]["target"]) < d1
        # Reset returns to the scene's camera.
        page.click("#reset")
        reset = self.wait_frame(page, zoomed["id"])
        assert reset["camera"] == page.evaluate("window.strataView.hello.camera")
        page.close()

    def test_method_and_options_give_the_cli_statistics(self):
        page = self.open_page(self.server.url)
        last = self.last_id(page)
        page.select_option("#method", "kbuffer")
        header = self.wait_frame(page, last)
        assert header["stats"]["method"] == "kbuffer"
        page.fill("input[data-option=k]", "2")
        page.locator("input[data-option=k]").dispatch_event("change")
        header = self.wait_frame(page, header["id"])
        stats = self.compare_with_render(page, header, "kbuffer-k2", "--method", "kbuffer", "-k", "2")
        for key in ("method", "fragments", "fragments_rasterized", "covered_pixels",
                    "max_depth_complexity", "depth_histogram", "dropped_fragments",
                    "memory_bytes", "used_memory_bytes"):
            assert header["stats"][key] == stats[key], (key, header["stats"][key], stats[key])
        assert header["stats"]["max_depth_complexity"] <= 2
        text = page.locator("#stats").inner_text()
        assert f"{stats['fragments']:,}" in text, text
        self.shot(page, "03-kbuffer-k2")
        # vkbuffer with its own options: the form offers exactly the options the method reads.
        last = header["id"]
        page.select_option("#method", "vkbuffer")
        header = self.wait_frame(page, last)
        offered = page.eval_on_selector_all("#options input", "els => els.map(e => e.dataset.option)")
        hello = page.evaluate("window.strataView.hello")
        reads = next(m["options"] for m in hello["methods"] if m["name"] == "vkbuffer")
        assert offered == [o for o in reads if o != "weights"], (offered, reads)
        page.close()

    def test_side_by_side_bad_pixels_and_flip_against_a_reference(self):
        page = self.open_page(self.server.url)
        # The frame before the change, read before it: the answer may come back before a read
        # after the change would happen.
        last = self.last_id(page)
        page.select_option("#method", "kbuffer")
        header = self.wait_frame(page, last)
        page.fill("input[data-option=k]", "2")
        page.locator("input[data-option=k]").dispatch_event("change")
        header = self.wait_frame(page, header["id"])
        page.select_option("#reference", "abuffer")
        header = self.wait_frame(page, header["id"])
        c = header["compare"]
        assert c["method"] == "abuffer" and c["mean_flip"] is None, c
        assert page.evaluate("document.getElementById('frame').width") == 2 * SIZE[0]
        self.compare_with_render(page, header, "side-main", "--method", "kbuffer", "-k", "2")
        self.compare_with_render(page, header, "side-ref", "--method", "abuffer", x0=SIZE[0])
        self.shot(page, "04-side-by-side")
        # The numbers and heat map of `strata compare` for the same view.
        scene = scene_with_view(self.strata, header["camera_toml"], self.tmp / "cmp.toml")
        out = self.tmp / "cmp"
        subprocess.run([self.strata, "compare", str(scene), "--methods", "kbuffer:k=2",
                        "--out-dir", str(out), "-j", "2"], check=True, capture_output=True)
        report = json.loads((out / "report.json").read_text())["methods"][0]
        assert c["bad_pixels"]["count"] == report["bad_pixels"]["count"], (c, report)
        assert abs(c["rmse"] - report["rmse"]) < 1e-12, (c, report)
        page.select_option("#show", "flip")
        header = self.wait_frame(page, header["id"])
        c = header["compare"]
        assert abs(c["mean_flip"] - report["mean_flip"]) < 1e-9, (c, report)
        assert page.evaluate("document.getElementById('frame').width") == SIZE[0]
        self.compare_with_png(page, out / report["flip_heatmap"], "flip heat map")
        self.shot(page, "04-flip")
        page.select_option("#show", "bad")
        header = self.wait_frame(page, header["id"])
        red = page.evaluate("""() => {
          const c = document.getElementById('frame');
          const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
          let n = 0;
          for (let i = 0; i < d.length; i += 4) if (d[i] === 220 && d[i + 1] === 20 && d[i + 2] === 60) n++;
          return n;
        }""")
        assert red == header["compare"]["bad_pixels"]["count"], (red, header["compare"])
        self.shot(page, "04-bad-pixels")
        page.close()

    def test_the_pixel_inspector_lists_the_deep_frame(self):
        page = self.open_page(self.server.url)
        header = page.evaluate("window.strataView.frame")
        # The centre of frame pixel (160, 90), through the canvas's object-fit: contain.
        box = page.locator("#frame").bounding_box()
        scale = min(box["width"] / SIZE[0], box["height"] / SIZE[1])
        left = box["x"] + (box["width"] - SIZE[0] * scale) / 2
        top = box["y"] + (box["height"] - SIZE[1] * scale) / 2
        page.mouse.click(left + (SIZE[0] // 2 + 0.5) * scale, top + (SIZE[1] // 2 + 0.5) * scale)
        page.wait_for_function("window.strataView.pixel !== null", timeout=15000)
        pixel = page.evaluate("window.strataView.pixel")
        assert pixel["frame"] == header["id"], "clicking must not move the camera"
        assert (pixel["x"], pixel["y"]) == (SIZE[0] // 2, SIZE[1] // 2), pixel
        assert len(pixel["fragments"]) >= 2, pixel
        # The same pixel of `strata render --deep`, read back by `strata inspect`.
        scene = scene_with_view(self.strata, header["camera_toml"], self.tmp / "pixel.toml")
        deep = self.tmp / "pixel.exr"
        subprocess.run([self.strata, "render", str(scene), "--out", str(self.tmp / "pixel.png"),
                        "--deep", str(deep), "-j", "2"], check=True, capture_output=True)
        listed = json.loads(subprocess.run(
            [self.strata, "inspect", str(deep), "--pixel", f"{pixel['x']},{pixel['y']}", "--json"],
            check=True, capture_output=True, text=True).stdout)["pixel"]["samples"]
        f32 = lambda v: struct.unpack("f", struct.pack("f", v))[0]
        assert len(listed) == len(pixel["fragments"]), (listed, pixel)
        for got, want in zip(pixel["fragments"], listed):
            assert f32(got["depth"]) == f32(want["strata.depth"]), (got, want)
            assert got["object"] == int(want["objectid"]), (got, want)
            assert abs(got["rgba"][3] / 255 - want["A"]) < 1e-6, (got, want)
            assert got["name"], got
        rows = page.locator("#pixel tbody tr").count()
        assert rows == len(listed), rows
        self.shot(page, "04-pixel-inspector")
        # The deep EXR button saves the frame's DeepFrame: strata inspect reads every fragment.
        with page.expect_download() as info:
            page.click("#save-deep")
        saved = self.tmp / "saved.exr"
        info.value.save_as(saved)
        read = json.loads(subprocess.run(
            [self.strata, "inspect", str(saved), "--pixel", f"{pixel['x']},{pixel['y']}", "--json"],
            check=True, capture_output=True, text=True).stdout)
        assert read["deep"] and read["samples"]["total"] == header["stats"]["fragments"], read["samples"]
        assert read["pixel"]["samples"] == listed, "the saved EXR differs from strata render --deep"
        page.close()

    def test_bad_option_shows_an_error_and_the_page_recovers(self):
        page = self.open_page(self.server.url)
        page.select_option("#method", "kbuffer")
        page.fill("input[data-option=k]", "0")
        page.locator("input[data-option=k]").dispatch_event("change")
        page.wait_for_selector("#error:not([hidden])")
        message = page.locator("#error").inner_text()
        assert "k" in message and "1" in message, message
        self.shot(page, "05-bad-option")
        last = self.last_id(page)
        page.fill("input[data-option=k]", "3")
        page.locator("input[data-option=k]").dispatch_event("change")
        header = self.wait_frame(page, last)
        assert header["stats"]["max_depth_complexity"] <= 3
        assert page.locator("#error").is_hidden()
        page.close()

    def test_malformed_messages_never_take_the_server_down(self):
        page = self.open_page(self.server.url)
        replies = page.evaluate("""async () => {
          const ws = new WebSocket(`ws://${location.host}/ws`);
          ws.binaryType = 'arraybuffer';
          const errors = [];
          ws.onmessage = (e) => { if (typeof e.data === 'string') {
            const m = JSON.parse(e.data); if (m.type === 'error') errors.push(m.message); } };
          await new Promise((r) => ws.onopen = r);
          const cam = window.strataView.hello.camera;
          const view = (patch) => JSON.stringify(Object.assign({type: 'view', id: 1, width: 64,
              height: 36, camera: cam, method: 'abuffer', options: {}}, patch));
          const bad = ['garbage', '{"type": "view"}', '{"type": "dance"}', '[1, 2, 3]',
            view({width: 100000}), view({method: 'nope'}), view({options: {k: '2'}}),
            view({camera: Object.assign({}, cam, {up: [0, 0, 0]})}),
            view({camera: Object.assign({}, cam, {eye: cam.target})}), view({frame: 99}),
            view({options: {weights: '/etc/passwd'}})];
          for (const m of bad) ws.send(m);
          ws.send(new Uint8Array([1, 2, 3]));
          const want = bad.length + 1;
          for (let i = 0; i < 100 && errors.length < want; i++) await new Promise((r) => setTimeout(r, 50));
          // A client that asks for a big frame and goes away before it is done.
          ws.send(view({width: 2048, height: 2048}));
          ws.close();
          return errors;
        }""")
        assert len(replies) == 12, replies
        assert all(r for r in replies), replies
        assert any("abuffer does not take k" in r for r in replies), replies
        assert self.server.alive(), "the server died"
        # The page is still served.
        last = self.last_id(page)
        self.drag(page, 40, 0)
        self.wait_frame(page, last)
        page.close()

    def test_a_killed_socket_reconnects(self):
        page = self.open_page(self.server.url)
        last = self.last_id(page)
        page.evaluate("window.strataView.socket.close()")
        page.wait_for_function("window.strataView.connects >= 2", timeout=15000)
        self.wait_frame(page, last)
        self.shot(page, "06-reconnected")
        page.close()

    def test_a_page_follows_a_restarted_server(self):
        first = Server(self.strata)
        second = None
        try:
            page = self.open_page(first.url)
            address = first.url.split("//")[1].rstrip("/")
            first.stop()
            page.wait_for_function("window.strataView.socket.readyState !== WebSocket.OPEN")
            second = Server(self.strata, scene="slabs", listen=address)
            # Another scene: the page reloads itself and shows the new server's.
            page.wait_for_function(
                "window.strataView && window.strataView.hello && window.strataView.hello.scene === 'slabs'",
                timeout=30000,
            )
            self.wait_frame(page, 0)
            assert "slabs" in page.locator("#scene").inner_text()
            page.close()
        finally:
            first.stop()
            if second is not None:
                second.stop()

    def test_many_pages_at_once_and_a_limit(self):
        pages = [self.browser.new_page() for _ in range(4)]
        for p in pages:
            p.goto(f"{self.server.url}?size=160x90")
        for p in pages:
            self.wait_frame(p, 0)
        for p in pages:
            p.close()
        limited = Server(self.strata, "--max-pages", "1")
        try:
            first = self.open_page(limited.url)
            second = self.browser.new_page()
            second.goto(limited.url)
            second.wait_for_selector("#error:not([hidden])")
            assert "too many pages" in second.locator("#error").inner_text()
            self.shot(second, "07-too-many-pages")
            second.close()
            first.close()
        finally:
            limited.stop()

    def wait_mfr(self, page, condition, what, timeout=60000):
        """Waits for a multi-frame-rate frame whose `header.mfr` meets the JS `condition` (on m)."""
        from playwright.sync_api import TimeoutError as Timeout

        try:
            page.wait_for_function(
                f"() => {{ const f = window.strataView.frame; const m = f && f.mfr;"
                f" return Boolean(m && ({condition})); }}",
                timeout=timeout,
            )
        except Timeout:
            state = page.evaluate("[window.strataView.frame && window.strataView.frame.mfr,"
                                  " window.strataView.errors]")
            raise AssertionError(f"no frame with {what}; last frame and errors: {state}")
        return page.evaluate("window.strataView.frame")

    def client_point(self, page, x, y):
        """The page coordinates of pixel (x, y) of the frame's main (left) image."""
        return page.evaluate(
            """([x, y]) => {
              const c = document.getElementById('frame'), r = c.getBoundingClientRect();
              const s = Math.min(r.width / c.width, r.height / c.height);
              const ox = (r.width - c.width * s) / 2, oy = (r.height - c.height * s) / 2;
              return [r.left + ox + x * s, r.top + oy + y * s, s];
            }""",
            [x, y],
        )

    def red_pixels(self, page):
        """Pixels of the bad-pixel map the page holds that are the map's red."""
        return page.evaluate(
            """() => {
              const b = window.strataView.images.bad;
              const c = new OffscreenCanvas(b.width, b.height).getContext('2d');
              c.drawImage(b, 0, 0);
              const d = c.getImageData(0, 0, b.width, b.height).data;
              let n = 0;
              for (let i = 0; i < d.length; i += 4)
                if (d[i] === 220 && d[i + 1] === 20 && d[i + 2] === 60) n++;
              return n;
            }"""
        )

    def test_mfr_a_drag_runs_ahead_of_the_slow_client_and_deep_stays_exact(self):
        server = Server(self.strata, "--mfr", scene="mfr-cars")
        try:
            page = self.browser.new_page(viewport={"width": 1200, "height": 700})
            page.on("pageerror", lambda e: self.page_errors.append(str(e)))
            page.goto(f"{server.url}?size=320x180")
            # Audited, the slow client held to one frame every two seconds; every frame's header
            # is kept.
            page.wait_for_function("window.strataView.hello !== null")
            page.evaluate("""() => { window.mfrFrames = [];
              window.addEventListener('strata-frame', (e) => window.mfrFrames.push(e.detail.mfr)); }""")
            page.check("#audit")
            page.fill("#sc-interval", "2000")
            page.dispatch_event("#sc-interval", "change")
            first = self.wait_mfr(page, "m.audit && m.sc_age_ms === 0", "an audited, settled frame")
            assert first["mfr"]["audit"]["bad_pixels"] == 0, first["mfr"]
            assert first["mfr"]["fc_objects"] == [], first["mfr"]
            self.shot(page, "08-mfr-start")

            # Hover the object the session offers: predictive migration hands it to the FC.
            hx, hy = first["mfr"]["handle_px"]
            x, y, s = self.client_point(page, hx, hy)
            page.mouse.move(x, y)
            over = self.wait_mfr(page, "m.over !== null && m.fc_objects.includes(m.over)",
                                 "the object under the pointer drawn by the FC")
            name = over["mfr"]["over"]

            # Press and drag six frame pixels to the right: the FC shows the object moving while
            # the SC buffer is older than the state, and the composite is still exact.
            page.mouse.down()
            for i in range(1, 7):
                page.mouse.move(x + i * s, y)
            held = self.wait_mfr(
                page,
                f"m.selected === {json.dumps(name)} && m.moved.length === 1 && m.audit"
                " && m.pointer_seq === window.strataView.pointerSeq",
                "the held object where the last pointer event put it",
            )
            m = held["mfr"]
            assert m["moved"][0]["name"] == name and m["moved"][0]["offset"][0] > 0, m
            assert m["audit"]["bad_pixels"] == 0, f"deep composition: {m}"
            assert self.red_pixels(page) == 0
            ahead = page.evaluate(
                f"window.mfrFrames.filter((m) => m.selected === {json.dumps(name)}"
                " && m.moved.length === 1 && m.sc_age_ms > 0 && m.audit)"
            )
            assert ahead, "no frame showed the drag before the slow client's buffer did"
            assert all(f["audit"]["bad_pixels"] == 0 for f in ahead), ahead
            self.shot(page, "09-mfr-drag-deep")

            # Digital composition (colour + depth) loses the wheel behind the windscreen: the
            # seed's fig. 6.6 artefact appears, and goes with deep composition.
            page.select_option("#composition", "digital")
            digital = self.wait_mfr(page, "m.composition === 'digital' && m.audit && m.sc_age_ms === 0"
                                    " && f.id === window.strataView.lastSentId", "a digital frame")
            a = digital["mfr"]["audit"]
            assert a["hole_pixels"] > 0 and a["bad_pixels"] > 0, a
            assert self.red_pixels(page) == a["bad_pixels"], (self.red_pixels(page), a)
            page.select_option("#mfr-show", "bad")
            page.wait_for_function("document.getElementById('frame').width === 320")
            self.shot(page, "10-mfr-digital-artefact")
            page.select_option("#composition", "deep")
            deep = self.wait_mfr(page, "m.composition === 'deep' && m.audit"
                                 " && f.id === window.strataView.lastSentId", "a deep frame again")
            assert deep["mfr"]["audit"]["bad_pixels"] == 0, deep["mfr"]
            page.select_option("#mfr-show", "side")

            # Released, it stays where it was left; the page inspects the composed fragments.
            page.mouse.up()
            after = self.wait_mfr(page, "m.selected === null && m.sc_age_ms === 0",
                                  "the released object in a settled frame")
            assert after["mfr"]["moved"] == m["moved"], (after["mfr"]["moved"], m["moved"])
            assert after["mfr"]["audit"]["bad_pixels"] == 0, after["mfr"]
            assert after["mfr"]["pointer_seq"] is not None
            self.shot(page, "11-mfr-released")
            # A click lists the composed pixel's fragments with the client of each: the wheel,
            # still under the pointer, is the FC's.
            hx, hy = after["mfr"]["handle_px"]
            x, y, _ = self.client_point(page, hx, hy)
            page.mouse.click(x, y)
            page.wait_for_function("window.strataView.pixel !== null")
            fragments = page.evaluate("window.strataView.pixel.fragments")
            assert any(f["name"] == name and f["client"] == "FC" for f in fragments), fragments
            assert all(f["client"] == ("FC" if f["name"] == name else "SC") for f in fragments)
            page.close()
            assert server.alive()
        finally:
            server.stop()

    def test_remote_orbits_the_nodes_and_shows_a_dead_one(self):
        # The scene still: a remote display poses it at its frame number, which keeps growing.
        source = without_animation(scene_source(self.strata))
        scene = self.tmp / "still.toml"
        scene.write_text(source)
        nodes = [Node(self.strata, scene, objects) for objects in ("0,1,2", "3,4,5")]
        server = None
        try:
            addrs = ",".join(n.addr for n in nodes)
            server = Server(self.strata, "--nodes", addrs, "--transfer", "difference",
                            "--timeout", "10", scene=str(scene))
            page = self.open_page(server.url)
            header = page.evaluate("window.strataView.frame")
            assert [n["status"] for n in header["remote"]["nodes"]] == ["ok", "ok"], header
            # Merged from two nodes, the frame is what one machine renders of the view.
            self.compare_with_render(page, header, "remote-first", source=source)
            rows = page.locator("#nodes tbody tr")
            assert rows.count() == 2
            assert "difference" in page.locator("#remote-note").inner_text()
            # Orbiting steers every node: the camera the frame reports renders to the canvas.
            self.drag(page, 100, 30)
            orbited = self.wait_frame(page, header["id"])
            assert orbited["camera"]["eye"] != header["camera"]["eye"]
            self.compare_with_render(page, orbited, "remote-orbited", source=source)
            self.shot(page, "12-remote-orbited")
            # The page switches the transfer; the display restarts with it.
            page.select_option("#transfer", "full")
            page.wait_for_function(
                "() => window.strataView.frame.remote.transfer === 'full'"
                " && window.strataView.frame.remote.nodes.every((n) => n.status === 'ok')",
                timeout=30000,
            )
            full = page.evaluate("window.strataView.frame")
            self.compare_with_render(page, full, "remote-full", source=source)
            # A node dies: its part is held, the table and the incidents say so.
            nodes[1].stop()
            page.wait_for_function(
                "() => document.querySelector('#nodes tbody tr:nth-child(2)')"
                " && document.querySelector('#nodes tbody tr:nth-child(2)').dataset.status === 'held'"
                " && document.querySelectorAll('#incidents li').length > 0",
                timeout=30000,
            )
            incidents = page.locator("#incidents").inner_text()
            assert nodes[1].addr in incidents, incidents
            held = page.evaluate("window.strataView.frame")
            assert held["remote"]["nodes"][0]["status"] == "ok", held["remote"]
            self.compare_with_render(page, held, "remote-held", source=source)
            self.shot(page, "13-remote-node-held")
            page.close()
            assert server.alive()
        finally:
            if server:
                server.stop()
            for n in nodes:
                n.stop()

    # ---- driver ---------------------------------------------------------------------------
    def run(self, only):
        from playwright.sync_api import sync_playwright

        tests = [n for n in dir(self) if n.startswith("test_") and (not only or only in n)]
        failed = []
        self.server = Server(self.strata)
        try:
            with sync_playwright() as pw:
                self.browser = pw.chromium.launch(
                    executable_path=self.browser_path, args=["--no-sandbox"]
                )
                for name in sorted(tests, key=lambda n: getattr(Suite, n).__code__.co_firstlineno):
                    self.page_errors = []
                    start = time.monotonic()
                    try:
                        getattr(self, name)()
                        assert not self.page_errors, f"errors in the page: {self.page_errors}"
                        print(f"ok    {name} ({time.monotonic() - start:.1f} s)")
                    except Exception:
                        failed.append(name)
                        print(f"FAIL  {name}\n{traceback.format_exc()}")
                self.browser.close()
        finally:
            self.server.stop()
        print(f"{len(tests) - len(failed)} passed, {len(failed)} failed; screenshots in {self.out}")
        return 1 if failed else 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--strata", default=str(ROOT / "target" / "debug" / "strata"))
    parser.add_argument("--out", default=str(ROOT / "target" / "browser-tests"))
    parser.add_argument("-k", dest="only", default="", help="run only tests whose name contains this")
    args = parser.parse_args()
    required = os.environ.get("STRATA_REQUIRE_TOOLS") == "1"
    browser = find_browser()
    try:
        import playwright  # noqa: F401
    except ImportError:
        browser = None
    if browser is None:
        message = "browser tests: Chromium or Playwright is missing (apt: chromium; pip: playwright)"
        if required:
            print(f"{message}; STRATA_REQUIRE_TOOLS=1, so this is a failure", file=sys.stderr)
            return 1
        print(f"{message}: SKIPPED", file=sys.stderr)
        return 0
    if not Path(args.strata).exists():
        print(f"browser tests: no strata binary at {args.strata}; build it first (cargo build)", file=sys.stderr)
        return 1
    return Suite(args.strata, args.out, browser).run(args.only)


if __name__ == "__main__":
    sys.exit(main())
