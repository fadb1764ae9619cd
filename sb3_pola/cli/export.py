"""``sb3-pola export MODEL.zip OUT [--format onnx|torchscript]``: a saved model's deterministic policy as one graph."""

from __future__ import annotations

import argparse

from sb3_pola.pola import POLA, export


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="sb3-pola export", description=export.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="a saved POLA model (.zip)")
    parser.add_argument("out", help="output file")
    parser.add_argument(
        "--format",
        choices=export.EXPORT_FORMATS,
        default=None,
        help=f"default: torchscript if OUT ends in {', '.join(export.TORCHSCRIPT_SUFFIXES)}, else onnx",
    )
    args = parser.parse_args(argv)
    model = POLA.load(args.model, device="cpu")
    fmt = args.format or export._infer_format(args.out)
    try:
        out = model.export_policy(args.out, format=fmt)
    except export.PolicyExportError as error:
        parser.exit(1, f"sb3-pola export: {error}\n")
    policy = model.policy
    print(
        f"wrote {out} ({fmt}): {export.INPUT_NAME} [batch, {policy.observation_space.shape[0]}] float32 -> "  # type: ignore[index]
        f"{export.OUTPUT_NAME} [batch, {policy.action_space.shape[0]}], {policy.predict_actor} actor, "  # type: ignore[index]
        f"{policy.n_diffusion_steps} denoising steps"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
