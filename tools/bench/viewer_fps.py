#!/usr/bin/env python3
"""Frames per second of `render-frame --serve`, as one page sees them: renders asked for one after another
through GET /render.png (orbiting the first target camera), at the full size and at the page's preview size,
for SECONDS each. Prints one line per size: frames per second over HTTP and the engine's median render time.

    python3 tools/bench/viewer_fps.py http://127.0.0.1:8765/ [SECONDS]
"""
import json
import math
import statistics
import sys
import time
import urllib.error
import urllib.request


def main():
    url = sys.argv[1].rstrip("/")
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 5.0
    info = json.load(urllib.request.urlopen(f"{url}/api/info"))
    scene, model = info["scenes"][0], info["models"][0]
    width, height = scene["sizes"][0]
    k = model["k"]
    preview = (max(k, width // 2 // k * k), max(k, height // 2 // k * k))
    pose = scene["pose"]
    for size in [(width, height), preview]:
        frames, limited, render_ms, start = 0, 0, [], time.monotonic()
        while time.monotonic() - start < seconds:
            # Turn the camera about the world z axis a degree a frame.
            a = math.radians(frames)
            c, s = math.cos(a), math.sin(a)
            turned = list(pose)
            for col in range(4):
                x, y = pose[col], pose[4 + col]
                turned[col], turned[4 + col] = c * x - s * y, s * x + c * y
            # No client id: the page's own id caps it at 60 frames a second, above what is measured here.
            query = f"pose={','.join(map(str, turned))}&size={size[0]}x{size[1]}"
            try:
                with urllib.request.urlopen(f"{url}/render.png?{query}") as response:
                    response.read()
                    render_ms.append(float(response.headers["X-Render-Ms"]))
            except urllib.error.HTTPError as error:
                # A GPU renders faster than the server's frame limit per address (429): wait for the next slot.
                if error.code != 429:
                    raise
                limited += 1
                time.sleep(0.002)
                continue
            frames += 1
        elapsed = time.monotonic() - start
        capped = f", capped by the server's frame limit ({limited} requests answered 429)" if limited else ""
        print(f"{size[0]}x{size[1]}: {frames / elapsed:.1f} fps over HTTP{capped}, render "
              f"{statistics.median(render_ms):.1f} ms (median of {frames}) on {info['adapter']} with {model['name']} "
              f"(k={k})")


if __name__ == "__main__":
    main()
