"""``cliff-terrain synthetic OUT.png``: write the project's own synthetic demo field."""

from __future__ import annotations

from pathlib import Path

HELP = "write the synthetic demo field (a photo the project generates itself) as a PNG"


def configure(parser):
    parser.add_argument("out", type=Path, help="PNG file to write")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--size", default="600x900", help="ROWSxCOLS (default 600x900)")
    parser.add_argument(
        "--canopy",
        choices=("open", "closed"),
        default="open",
        help="open: separate plants; closed: rows joined at their ends around soil strips (default open)",
    )


def run(args):
    from PIL import Image

    from ..data.synthetic import synthetic_field
    from ..errors import CliffTerrainError

    try:
        rows, cols = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise CliffTerrainError(
            f"`--size` must be ROWSxCOLS, for example 600x900, got {args.size!r}"
        ) from None
    image, truth = synthetic_field(shape=(rows, cols), seed=args.seed, canopy=args.canopy)
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(args.out)
    except (OSError, ValueError) as exc:
        raise CliffTerrainError(f"cannot write {str(args.out)!r}: {exc}") from None
    print(f"wrote {args.out} ({cols}x{rows}, {truth.n_plants} plants, seed {args.seed})")
    return 0
