#!/usr/bin/env python3
"""Browsers: the Deep Zoom, IIIF Image API 3.0 and XYZ endpoints against their specs' rules, CORS
and tokens as a browser uses them, and the web viewer (/view/{name}) in a real headless
Chromium, its screenshots compared with the source image resampled by ImageMagick.

Images come from ImageMagick (and oiiotool for a float one), not from Tessera.
  web_viewer_test.py --tessera BIN --node-modules DIR [--chromium PATH]
"""
import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import urllib.error
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from serve_util import wait_listening  # noqa: E402

failures = []
JPEG_TILE_DB = 43.0  # measured 44.6 (edge) and 46.2 dB


def check(cond, what, show=False):
    if show and cond:
        print("ok:", what, flush=True)
    if not cond:
        failures.append(what)
        print("FAIL:", what, flush=True)
    return cond


def get(port, path, headers=None, method="GET"):
    req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", headers=headers or {}, method=method)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), e.read()


class NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args, **kwargs):
        return None


def rgb(path_or_bytes, crop=None, resize=None, filt=None):
    """Texels as 8-bit RGB bytes through ImageMagick (alpha flattened onto black)."""
    src = "-" if isinstance(path_or_bytes, bytes) else path_or_bytes
    cmd = ["convert", src, "-background", "black", "-alpha", "remove"]
    if filt:
        cmd += ["-filter", filt]
    if resize:
        cmd += ["-resize", resize]
    if crop:
        cmd += ["-crop", "%dx%d+%d+%d" % crop, "+repage"]
    cmd += ["-depth", "8", "rgb:-"]
    return subprocess.run(cmd, input=path_or_bytes if src == "-" else None, capture_output=True, check=True).stdout


def size_of(data):
    out = subprocess.run(["identify", "-format", "%w %h", "-"], input=data, capture_output=True, check=True).stdout
    w, h = out.split()
    return int(w), int(h)


def psnr(a, b):
    n = min(len(a), len(b))
    if n == 0 or len(a) != len(b):
        return -1.0
    se = sum((x - y) * (x - y) for x, y in zip(a, b))
    return 99.0 if se == 0 else 10 * math.log10(255 * 255 * n / se)


def column_errors(a, b, w, h):
    """Mean absolute error of each column and each row of two w x h RGB images."""
    cols, rows = [0.0] * w, [0.0] * h
    for y in range(h):
        base = y * w * 3
        for x in range(w):
            i = base + x * 3
            e = abs(a[i] - b[i]) + abs(a[i + 1] - b[i + 1]) + abs(a[i + 2] - b[i + 2])
            cols[x] += e
            rows[y] += e
    return [c / (3 * h) for c in cols], [r / (3 * w) for r in rows]


def spec_checks(port, name, width, height, tile, overlap):
    # ---- Deep Zoom ----
    st, hd, body = get(port, f"/dzi/{name}.dzi")
    check(st == 200 and hd.get("Content-Type", "").startswith("application/xml"), f"{name}.dzi: {st}")
    xml = body.decode()
    m = re.search(r'TileSize="(\d+)" Overlap="(\d+)" Format="(\w+)".*Width="(\d+)" Height="(\d+)"', xml, re.S)
    check(m is not None, f"{name}.dzi parses: {xml}")
    ts, ov, fmt, w, h = int(m[1]), int(m[2]), m[3], int(m[4]), int(m[5])
    check((ts, ov, w, h) == (tile, overlap, width, height), f"{name}.dzi says {ts} {ov} {w}x{h}")
    max_level = math.ceil(math.log2(max(w, h)))
    check(get(port, f"/dzi/{name}_files/{max_level + 1}/0_0.{fmt}")[0] == 404, "DZI level past the last: 404")
    for level in list(range(0, 4)) + [max_level - 2, max_level]:
        lw, lh = w, h
        for _ in range(max_level - level):
            lw, lh = (lw + 1) // 2, (lh + 1) // 2
        cols, rows = math.ceil(lw / ts), math.ceil(lh / ts)
        for x in range(cols):
            for y in range(rows):
                if level == max_level and 0 < x < cols - 1 and 0 < y < rows - 1 and (x + y) % 3:
                    continue  # a sample of the interior: every edge tile, a third of the rest
                st, hd, data = get(port, f"/dzi/{name}_files/{level}/{x}_{y}.{fmt}")
                if not check(st == 200, f"DZI {level}/{x}_{y}: {st} {data[:120]}"):
                    continue
                # DZI's rule: the tile's own square plus the overlap on each side, except past
                # the image's edges.
                ew = min((x + 1) * ts + ov, lw) - max(x * ts - ov, 0)
                eh = min((y + 1) * ts + ov, lh) - max(y * ts - ov, 0)
                check(size_of(data) == (ew, eh), f"DZI {level}/{x}_{y} is {size_of(data)}, not {ew}x{eh}")
        check(get(port, f"/dzi/{name}_files/{level}/{cols}_0.{fmt}")[0] == 404, f"DZI {level}: column {cols} is 404")
        check(get(port, f"/dzi/{name}_files/{level}/0_{rows}.{fmt}")[0] == 404, f"DZI {level}: row {rows} is 404")
    for bad in ["/dzi/{n}_files/x/0_0.jpg", "/dzi/{n}_files/1/0-0.jpg", "/dzi/{n}_files/1/0_0.gif",
                "/dzi/{n}_files/01/0_0.jpg"]:
        check(get(port, bad.format(n=name))[0] == 400, f"DZI {bad}: 400")
    check(get(port, "/dzi/nosuch.dzi")[0] == 404, "DZI unknown store: 404")

    # ---- IIIF Image API 3.0 ----
    opener = urllib.request.build_opener(NoRedirect)
    try:
        opener.open(f"http://127.0.0.1:{port}/iiif/{name}")
        check(False, "IIIF base URI redirects")
    except urllib.error.HTTPError as e:
        check(e.code == 303 and e.headers["Location"].endswith(f"/iiif/{name}/info.json"), f"IIIF base URI: {e.code}")
    st, hd, body = get(port, f"/iiif/{name}/info.json")
    info = json.loads(body)
    check(st == 200 and hd["Content-Type"] == "application/json", f"info.json {st} {hd.get('Content-Type')}")
    st, hd, _ = get(port, f"/iiif/{name}/info.json", {"Accept": "application/ld+json"})
    check(hd["Content-Type"].startswith("application/ld+json"), "info.json as JSON-LD when asked")
    for key, want in [("@context", "http://iiif.io/api/image/3/context.json"), ("type", "ImageService3"),
                      ("protocol", "http://iiif.io/api/image"), ("profile", "level2"), ("width", width),
                      ("height", height)]:
        check(info.get(key) == want, f"info.json {key} = {info.get(key)!r}")
    check(re.match(r"^https?://[^/]+/iiif/" + re.escape(name) + "$", info["id"]) is not None, f"info.json id {info['id']}")
    t = info["tiles"][0]
    check(t["width"] == tile and t.get("height", tile) == tile, f"info.json tile size {t}")
    factors = t["scaleFactors"]
    check(factors == [2 ** i for i in range(len(factors))], f"scale factors {factors}")
    sizes = info["sizes"]
    check(sizes == sorted(sizes, key=lambda s: s["width"]) and sizes[-1]["width"] <= info["maxWidth"], f"sizes {sizes}")
    # Every tile the info.json implies, at every scale factor (a sample at the finest).
    for sf in factors:
        span = tile * sf
        cols, rows = math.ceil(width / span), math.ceil(height / span)
        for x in range(cols):
            for y in range(rows):
                if sf == 1 and (x + y) % 4:
                    continue
                rx, ry = x * span, y * span
                rw, rh = min(span, width - rx), min(span, height - ry)
                ow, oh = math.ceil(rw / sf), math.ceil(rh / sf)
                st, hd, data = get(port, f"/iiif/{name}/{rx},{ry},{rw},{rh}/{ow},{oh}/0/default.jpg")
                if check(st == 200, f"IIIF tile sf {sf} ({x},{y}): {st} {data[:100]}"):
                    check(size_of(data) == (ow, oh), f"IIIF tile sf {sf} ({x},{y}) is {size_of(data)}, not {ow}x{oh}")
    for s in sizes:
        st, _, data = get(port, f"/iiif/{name}/full/{s['width']},{s['height']}/0/default.png")
        check(st == 200 and size_of(data) == (s["width"], s["height"]), f"IIIF listed size {s}: {st}")
    for path, want in [("full/max/0/default.jpg", 200), ("square/100,/0/default.jpg", 200),
                       ("pct:10,10,50,50/pct:25/0/color.png", 200), ("full/!200,200/90/gray.jpg", 200),
                       ("full/^max/!180/default.png", 200), ("0,0,10,10/^40,40/270/default.jpg", 200),
                       # invalid: 400; valid but not implemented: 501
                       ("0,0,0,10/max/0/default.jpg", 400), (f"{width},0,10,10/max/0/default.jpg", 400),
                       ("a,b,c,d/max/0/default.jpg", 400), ("full/0,/0/default.jpg", 400),
                       (f"full/{width + 1},/0/default.jpg", 400), ("full/max/0/default.gif", 501),
                       ("full/max/45/default.jpg", 501), ("full/max/0/bitonal.jpg", 501),
                       ("full/max/0/fancy.jpg", 400), ("full/max/400/default.jpg", 400), ("full/max/0/default", 400),
                       ("full/max/0", 400)]:
        st, _, data = get(port, f"/iiif/{name}/{path}")
        check(st == want, f"IIIF {path}: {st}, expected {want} ({data[:100]})")
    # Rotation and mirroring: the unrotated image turned by ImageMagick, texel for texel (PNG is
    # lossless, so any wrong direction or flip shows); gray: ImageMagick's Rec. 709 luma of the
    # colour image (IIIF leaves the weights to the server; these are the ones Tessera documents).
    upright = get(port, f"/iiif/{name}/full/!200,200/0/default.png")[2]
    fw, fh = size_of(upright)
    for rotation, im_ops in [("90", ["-rotate", "90"]), ("180", ["-rotate", "180"]), ("270", ["-rotate", "270"]),
                             ("!0", ["-flop"]), ("!90", ["-flop", "-rotate", "90"])]:
        st, _, data = get(port, f"/iiif/{name}/full/!200,200/{rotation}/default.png")
        turned = subprocess.run(["convert", "-", "-background", "black", "-alpha", "remove"] + im_ops + ["-depth", "8", "rgb:-"],
                                input=upright, capture_output=True, check=True).stdout
        want_size = (fh, fw) if rotation.lstrip("!") in ("90", "270") else (fw, fh)
        check(st == 200 and size_of(data) == want_size, f"IIIF rotation {rotation}: {st}, {size_of(data)} for {want_size}")
        check(rgb(data) == turned, f"IIIF rotation {rotation} is ImageMagick's turn of the upright image, texel for texel")
    st, _, data = get(port, f"/iiif/{name}/full/!200,200/0/gray.png")
    grey = subprocess.run(["convert", "-", "-background", "black", "-alpha", "remove", "-grayscale", "Rec709Luma", "-depth", "8",
                           "rgb:-"], input=upright, capture_output=True, check=True).stdout
    have = rgb(data)
    worst = max(abs(x - y) for x, y in zip(have, grey)) if len(have) == len(grey) else 255
    check(st == 200 and size_of(data) == (fw, fh) and worst <= 1,
          f"IIIF gray is ImageMagick's Rec. 709 luma of the colour image within 1 (max difference {worst})", True)
    # pct: regions are the image's percentages: the same texels as the pixel region they name.
    half_up = lambda v: int(math.floor(v + 0.5))  # noqa: E731 (the server rounds halves up, Python's round() to even)
    px = (half_up(width * 0.1), half_up(height * 0.2), half_up(width * 0.5), half_up(height * 0.4))
    st, _, by_pct = get(port, f"/iiif/{name}/pct:10,20,50,40/!256,256/0/default.png")
    st2, _, by_px = get(port, f"/iiif/{name}/{px[0]},{px[1]},{px[2]},{px[3]}/!256,256/0/default.png")
    check(st == 200 and st2 == 200 and rgb(by_pct) == rgb(by_px), f"IIIF pct:10,20,50,40 is the region {px}")
    st, _, data = get(port, f"/iiif/{name}/full/!{width * 3},{height * 3}/0/default.png")
    check(st == 200 and size_of(data) == (width, height), "IIIF !w,h larger than the image gives the image's size")
    st, _, data = get(port, f"/iiif/{name}/0,0,{width},8/1,8/0/default.png")
    check(st == 200 and size_of(data) == (1, 8), "IIIF: a size stretched along one axis")
    check(get(port, "/iiif/nosuch/info.json")[0] == 404, "IIIF unknown store: 404")

    # ---- XYZ ----
    levels = len(factors)
    for z in range(levels):
        k = levels - 1 - z
        lw, lh = math.ceil(width / 2 ** k), math.ceil(height / 2 ** k)
        cols, rows = math.ceil(lw / tile), math.ceil(lh / tile)
        st, _, data = get(port, f"/xyz/{name}/{z}/{cols - 1}/{rows - 1}.png")
        check(st == 200 and size_of(data) == (tile, tile), f"XYZ {z}/{cols - 1}/{rows - 1}: {st}")
        check(get(port, f"/xyz/{name}/{z}/{cols}/0.png")[0] == 404, f"XYZ {z}: column {cols} is 404")
    check(get(port, f"/xyz/{name}/{levels}/0/0.png")[0] == 404, "XYZ zoom past the finest: 404")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    ap.add_argument("--node-modules", required=True)
    ap.add_argument("--chromium", default="/usr/bin/chromium")
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="tessera_web_")
    stores = os.path.join(tmp, "stores")
    os.makedirs(stores)
    # A detailed 8-bit photo-like image (JPEG store), an odd-sized one with alpha (zstd, PNG
    # tiles), a 16-bit one and a float one (no web view).
    src = os.path.join(tmp, "pic.png")
    subprocess.run(["convert", "-seed", "11", "-size", "1900x1300", "plasma:tomato-steelblue", "-blur", "0x1.2",
                    "-depth", "8", "-type", "TrueColor", src], check=True)
    alpha_src = os.path.join(tmp, "alpha.png")
    subprocess.run(["convert", "-seed", "5", "-size", "777x555", "plasma:", "(", "-size", "777x555", "gradient:white-black",
                    ")", "-alpha", "off", "-compose", "CopyOpacity", "-composite", "-depth", "8", alpha_src], check=True)
    deep_src = os.path.join(tmp, "deep.png")
    # 1024 wide: a power-of-two side, where DZI's level count ceil(log2(side)) is easiest to get wrong.
    subprocess.run(["convert", "-size", "1024x400", "gradient:black-white", "-depth", "16", deep_src], check=True)
    float_src = os.path.join(tmp, "float.exr")
    subprocess.run(["oiiotool", "--pattern", "fill:topleft=0,0,0:topright=1,0,0:bottomleft=0,1,0:bottomright=1,1,1",
                    "300x200", "3", "-d", "float", "-o", float_src], check=True)
    for name, path, extra in [("pic", src, []), ("alpha", alpha_src, ["--codec", "zstd"]),
                              ("deep", deep_src, []), ("float", float_src, [])]:
        subprocess.run([a.tessera, "build", path, "-o", os.path.join(stores, name + ".tsr"), "-q"] + extra, check=True)

    p = subprocess.Popen([a.tessera, "serve", "--store-dir", stores, "--grpc", "", "--http", "127.0.0.1:0"],
                         stderr=subprocess.PIPE, text=True)
    try:
        ports = wait_listening(p)
        if not check(ports is not None, "server listens"):
            return 1
        port = ports[1]
        spec_checks(port, "pic", 1900, 1300, 248, 4)
        spec_checks(port, "alpha", 777, 555, 248, 4)
        spec_checks(port, "deep", 1024, 400, 248, 4)
        check(re.search(r'Format="png"', get(port, "/dzi/alpha.dzi")[2].decode()) is not None, "alpha store: PNG tiles")
        check(re.search(r'Format="jpg"', get(port, "/dzi/pic.dzi")[2].decode()) is not None, "JPEG store: JPEG tiles")

        # Interior DZI tiles of a JPEG store are the stored tiles themselves; edge ones are crops.
        level = math.ceil(math.log2(1900))
        _, _, stored = get(port, "/v1/stores/pic/tiles/0/1/1")
        _, _, dzi = get(port, f"/dzi/pic_files/{level}/1/1.jpg".replace("/1/1.jpg", "/1_1.jpg"))
        check(stored == dzi, "an interior DZI tile is the stored JPEG, byte for byte")
        ref = rgb(src, crop=(256, 256, 248 * 2 - 4, 248 - 4))
        value = psnr(rgb(get(port, f"/dzi/pic_files/{level}/2_1.jpg")[2]), ref)
        check(value >= JPEG_TILE_DB, f"DZI tile matches the source ({value:.2f} dB)", True)
        edge = get(port, f"/dzi/pic_files/{level}/0_0.jpg")[2]
        value = psnr(rgb(edge), rgb(src, crop=(252, 252, 0, 0)))
        check(value >= JPEG_TILE_DB, f"DZI edge tile is the source's corner ({value:.2f} dB)", True)
        # A crop that starts and ends between the texels of the level it is made from.
        st, _, data = get(port, "/iiif/pic/101,103,401,299/133,99/0/default.png")
        want = subprocess.run(["convert", src, "-crop", "401x299+101+103", "+repage", "-resize", "133x99!", "-depth", "8",
                               "rgb:-"], capture_output=True, check=True).stdout
        value = psnr(rgb(data), want)
        check(st == 200 and value >= 41, f"IIIF crop between texels matches ImageMagick's ({value:.2f} dB)", True)
        # 16-bit: shown at 8 bits; float: no web view, said so.
        st, _, data = get(port, "/iiif/deep/full/max/0/default.png")
        value = psnr(rgb(data), rgb(deep_src))
        check(st == 200 and value >= 49, f"16-bit store shown at 8 bits ({value:.2f} dB)", True)
        st, _, body = get(port, "/view/float")
        check(st == 415 and b"f32" in body, f"float store: no viewer, and why ({st} {body[:100]})")
        check(get(port, "/dzi/float.dzi")[0] == 406, "float store: no DZI")

        # CORS and caching as for /v1.
        st, hd, _ = get(port, "/iiif/pic/0,0,248,248/248,/0/default.jpg", {"Origin": "https://example.org"})
        check(hd.get("Access-Control-Allow-Origin") == "*", "CORS on an image")
        etag = hd.get("ETag")
        st2, _, _ = get(port, "/iiif/pic/0,0,248,248/248,/0/default.jpg", {"If-None-Match": etag})
        check(st2 == 304, f"If-None-Match gives 304 ({st2})")
        st, hd, _ = get(port, "/dzi/pic.dzi", {"Origin": "https://example.org", "Access-Control-Request-Method": "GET",
                                               "Access-Control-Request-Headers": "authorization"}, method="OPTIONS")
        check(st == 204 and hd.get("Access-Control-Allow-Origin") == "*" and "Authorization" in
              hd.get("Access-Control-Allow-Headers", ""), f"preflight: {st} {hd}")
        st, _, body = get(port, "/")
        check(st == 200 and b'href="/view/pic"' in body, "the store list links the viewer")

        # The viewer in Chromium: 1:1, 1:2 and the home view, each against ImageMagick's resampling.
        views = [{"zoom": 1, "cx": 980, "cy": 640}, {"zoom": 0.5, "cx": 950, "cy": 650}, {"zoom": "home"}]
        env = dict(os.environ, NODE_PATH=a.node_modules, CHROMIUM=a.chromium)
        drive = subprocess.run(["node", os.path.join(os.path.dirname(os.path.abspath(__file__)), "web_viewer_drive.js"),
                                f"http://127.0.0.1:{port}/view/pic", tmp, json.dumps(views)],
                               capture_output=True, text=True, env=env, timeout=240)
        if not check(drive.returncode == 0, f"browser run: {drive.stderr[-2000:]}"):
            return 1
        result = json.loads(drive.stdout.strip().splitlines()[-1])
        check(result["problems"] == [], f"the page loaded cleanly: {result['problems']}")
        for i, (v, placed) in enumerate(zip(views, result["views"])):
            shot = os.path.join(tmp, f"view_{i}.png")
            W, H = size_of(open(shot, "rb").read())
            # Where the request puts the image: the zoom's scale with (cx, cy) at the viewer's
            # centre, or home, the whole image fitted and centred. OpenSeadragon's own account of
            # the placement must agree, and the reference is cut out where the request says.
            if v["zoom"] == "home":
                scale = min(W / 1900.0, H / 1300.0)
                x0, y0 = (W - 1900 * scale) / 2, (H - 1300 * scale) / 2
            else:
                scale = float(v["zoom"])
                x0, y0 = W / 2 - v["cx"] * scale, H / 2 - v["cy"] * scale
            osd_scale = (placed["x1"] - placed["x0"]) / 1900.0
            check(abs(osd_scale - scale) <= 1e-3 * scale and abs(placed["x0"] - x0) <= 0.5 and abs(placed["y0"] - y0) <= 0.5,
                  f"view {i}: the image is at ({placed['x0']:.2f}, {placed['y0']:.2f}) scale {osd_scale:.4f}, "
                  f"the request puts it at ({x0:.2f}, {y0:.2f}) scale {scale:.4f}")
            placed = dict(placed, x1=x0 + 1900 * scale, y1=y0 + 1300 * scale)
            # The part of the screenshot the image covers, in whole pixels, and the source there.
            sx0, sy0 = max(0, math.ceil(x0 - 1e-6)), max(0, math.ceil(y0 - 1e-6))
            sx1, sy1 = min(W, math.floor(placed["x1"] + 1e-6)), min(H, math.floor(placed["y1"] + 1e-6))
            w, h = sx1 - sx0, sy1 - sy0
            got = rgb(shot, crop=(w, h, sx0, sy0))
            resized_w, resized_h = round(1900 * scale), round(1300 * scale)
            filt = "box" if v["zoom"] in (1, 0.5) else None
            want = rgb(src, resize=f"{resized_w}x{resized_h}!", filt=filt,
                       crop=(w, h, round(sx0 - x0), round(sy0 - y0)))
            value = psnr(got, want)
            print(f"view {i} ({v['zoom']}): image at ({x0:.2f}, {y0:.2f}) scale {scale:.4f}, {w}x{h} compared, "
                  f"PSNR {value:.2f} dB, drawer {placed['drawer']}", flush=True)
            # Measured 46.2, 41.2 and 40.4 dB (1:1, 1:2, home; Chromium's WebGL drawer).
            need = {1: 44.0, 0.5: 39.5, "home": 38.5}[v["zoom"]]
            check(value >= need, f"view {i}: PSNR {value:.2f} dB against ImageMagick's resampling (needs {need})")
            if v["zoom"] == 1:
                # Seams: the columns and rows at tile joins are no worse than the rest.
                cols, rows = column_errors(got, want, w, h)
                joins_x = [j for j in range(w) if (j + sx0 - round(x0)) % 248 in (0, 247)]
                joins_y = [j for j in range(h) if (j + sy0 - round(y0)) % 248 in (0, 247)]
                inner = sorted(cols + rows)[len(cols + rows) // 2]
                worst = max([cols[j] for j in joins_x] + [rows[j] for j in joins_y])
                print(f"  seams: worst join column/row error {worst:.3f}, median column/row {inner:.3f}", flush=True)
                check(worst <= 1.5 * inner + 0.5, f"tile joins show: {worst:.3f} against {inner:.3f}")

        # Tokens as a browser sends them: header, ?access_token= (then a cookie), cookie.
        p.terminate()
        p.wait(timeout=20)
        token_file = os.path.join(tmp, "token")
        with open(token_file, "w") as f:
            f.write("s3cret\n")
        p = subprocess.Popen([a.tessera, "serve", "--store-dir", stores, "--grpc", "", "--http", "127.0.0.1:0",
                              "--auth-token-file", token_file], stderr=subprocess.PIPE, text=True)
        port = wait_listening(p)[1]
        check(get(port, "/view/pic")[0] == 401, "viewer without a token: 401")
        st, hd, _ = get(port, "/view/pic?access_token=s3cret")
        check(st == 200 and "tessera_token=s3cret" in hd.get("Set-Cookie", ""), f"?access_token= sets a cookie ({st})")
        check(get(port, "/dzi/pic_files/0/0_0.jpg", {"Cookie": "tessera_token=s3cret"})[0] == 200, "cookie token")
        check(get(port, "/dzi/pic_files/0/0_0.jpg", {"Cookie": "tessera_token=wrong"})[0] == 401, "wrong cookie: 401")
        check(get(port, "/iiif/pic/info.json", {"Authorization": "Bearer s3cret"})[0] == 200, "bearer header")
        check(get(port, "/xyz/pic/0/0/0.png?access_token=s3cret")[0] == 200, "query token")
        check(get(port, "/xyz/pic/0/0/0.png?access_token=nope")[0] == 401, "wrong query token: 401")
    finally:
        p.terminate()
        p.wait(timeout=20)
    if failures:
        print(f"{len(failures)} failures", flush=True)
        return 1
    print("ok", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
