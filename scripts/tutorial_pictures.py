"""Make docs/tutorial.md's pictures from a run of the page, and show what each command printed.

    .venv/bin/python scripts/tutorial_pictures.py            # needs tmux and chromium on PATH
    .venv/bin/python scripts/tutorial_pictures.py --outputs run.txt

The run is the test's (tests/demo/tutorial_page.py: every command block in order, real
processes, each sample output checked); the steps marked ``picture=FILE`` (a screenshot of the
viewer in headless Chromium) and ``picture PATH FILE`` (a PNG a command wrote, fleet-map's map)
are written to docs/img/FILE, as palette PNGs to keep them small. ``--outputs`` writes every
command's real output, for the page's ```console blocks.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from PIL import Image  # noqa: E402

from tests.demo.tutorial_page import run_page  # noqa: E402

IMG = ROOT / "docs" / "img"
MAX_BYTES = 200_000


def shrink(path: Path) -> None:
    """A palette PNG (256 colours): a screenshot of flat colours loses nothing visible."""
    img = Image.open(path).convert("RGB")
    out = io.BytesIO()
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(out, "PNG", optimize=True)
    path.write_bytes(out.getvalue())
    if len(out.getvalue()) > MAX_BYTES:
        raise SystemExit(f"{path.name}: {len(out.getvalue())} bytes, more than {MAX_BYTES}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--outputs", type=Path, help="write what every command printed to this file")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        pictures = Path(tmp) / "pictures"
        pictures.mkdir()
        checkout = Path(tmp) / "checkout"
        checkout.mkdir()
        run = run_page(checkout, pictures=pictures, echo=print)
        for png in sorted(pictures.iterdir()):
            shrink(png)
            (IMG / png.name).write_bytes(png.read_bytes())
            print(f"wrote docs/img/{png.name} ({png.stat().st_size} bytes)")
        if args.outputs:
            args.outputs.write_text("".join(f"==== {s.where()} {s.text}\n{out}\n" for s, out in run.outputs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
