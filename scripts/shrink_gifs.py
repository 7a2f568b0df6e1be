"""Shrink committed GIFs to at most 1.5 MB each (the repository's weight rule), in place.

    python scripts/shrink_gifs.py $(git ls-files '*.gif')          # shrink those over the limit
    python scripts/shrink_gifs.py --dry-run $(git ls-files '*.gif')

A GIF over the limit is re-encoded with the first setting of `LADDER` that fits, each step losing a
little more of what a reader sees: every other frame (the duration, so the playback speed, is
kept: each frame shows twice as long), then a smaller global palette, then every third frame,
then a smaller frame. One global palette (median cut over a dozen frames spread over the clip),
no dithering: the renders' textured boxes turn dithering into noise that LZW cannot compress.
Prints a Markdown table of each GIF before and after (size, frame size, frames, fps, duration).
Pillow only (matplotlib's dependency).
"""

from __future__ import annotations

import argparse
import io
import pathlib
import sys

from PIL import Image

LIMIT = 1_500_000  # bytes
TARGET = 1_450_000  # what the ladder aims under, for a margin
# (keep every n-th frame, frame size as a fraction of the original's, palette colours)
LADDER = [(2, 1.0, 128), (2, 1.0, 64), (2, 1.0, 32), (3, 1.0, 64), (3, 0.85, 64), (3, 0.75, 64),
          (4, 0.75, 64), (4, 0.67, 48)]
NTH = {2: "every other", 3: "every third", 4: "every fourth"}


def load(path) -> tuple[list, int]:
    """(RGB frames, the first frame's duration in ms)."""
    im = Image.open(path)
    frames = []
    for i in range(im.n_frames):
        im.seek(i)
        frames.append(im.convert("RGB"))
    im.seek(0)
    return frames, int(im.info.get("duration", 60))


def describe(path) -> dict:
    im = Image.open(path)
    durs = []
    for i in range(im.n_frames):
        im.seek(i)
        durs.append(int(im.info.get("duration", 0)))
    total = sum(durs) / 1000
    return {"bytes": pathlib.Path(path).stat().st_size, "size": im.size, "frames": im.n_frames,
            "fps": im.n_frames / total if total else float("nan"), "duration_s": total}


def encode(frames, duration_ms: int, every: int, scale: float, colors: int) -> bytes:
    fr = frames[::every]
    if scale != 1.0:
        w, h = fr[0].size
        size = (2 * round(w * scale / 2), 2 * round(h * scale / 2))
        fr = [f.resize(size, Image.BILINEAR) for f in fr]
    n = min(12, len(fr))
    picks = [round(i * (len(fr) - 1) / max(n - 1, 1)) for i in range(n)]
    sample = Image.new("RGB", (fr[0].width, fr[0].height * n))
    for k, i in enumerate(picks):
        sample.paste(fr[i], (0, k * fr[0].height))
    palette = sample.quantize(colors=colors, method=Image.Quantize.MEDIANCUT)
    q = [f.quantize(palette=palette, dither=Image.Dither.NONE) for f in fr]
    buf = io.BytesIO()
    q[0].save(buf, "GIF", save_all=True, append_images=q[1:], duration=duration_ms * every,
              loop=0, optimize=True)
    return buf.getvalue()


def shrink(path: pathlib.Path, dry_run: bool = False) -> tuple[dict, dict, str]:
    """(before, after, the setting used) for one GIF; one under the limit is left alone."""
    before = describe(path)
    if before["bytes"] <= LIMIT:
        return before, before, "unchanged"
    frames, dur = load(path)
    for every, scale, colors in LADDER:
        data = encode(frames, dur, every, scale, colors)
        if len(data) <= TARGET:
            break
    else:
        raise SystemExit(f"{path}: no setting of the ladder fits under {LIMIT:,} bytes")
    setting = (f"{NTH[every]} frame, {colors} colours"
               + ("" if scale == 1 else f", frame x{scale:g}"))
    out = path if not dry_run else pathlib.Path("/tmp") / f"shrunk_{path.name}"
    out.write_bytes(data)
    return before, describe(out), setting


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("gifs", nargs="+", type=pathlib.Path)
    p.add_argument("--dry-run", action="store_true", help="write the results to /tmp instead")
    a = p.parse_args(argv)
    print("| GIF | before: MB, frame, frames, fps, s | after: MB, frame, frames, fps, s | how |")
    print("|---|---|---|---|")
    for g in a.gifs:
        b, f, how = shrink(g, a.dry_run)

        def cell(d):
            return (f"{d['bytes'] / 1e6:.2f}, {d['size'][0]}x{d['size'][1]}, {d['frames']}, "
                    f"{d['fps']:.1f}, {d['duration_s']:.1f}")

        print(f"| `{g}` | {cell(b)} | {cell(f)} | {how} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
