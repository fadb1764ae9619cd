"""``sb3-pola export MODEL.zip OUT [--format onnx|torchscript]``: a saved model's deterministic policy as one graph."""

from __future__ import annotations

import pathlib

from sb3_pola.common.arguments import ArgumentParser
from sb3_pola.common.errors import UsageError
from sb3_pola.pola import POLA, export

# the file extensions of each format: OUT must end in one of its format's
FORMAT_SUFFIXES = {"onnx": (".onnx",), "torchscript": export.TORCHSCRIPT_SUFFIXES}


def output_format(out: str, fmt: str | None) -> str:
    """The export format of ``out``: ``fmt`` if given, else its extension's; the extension must be the format's.

    :param out: the output file
    :param fmt: ``--format`` (``None``: from the extension)
    :return: ``"onnx"`` or ``"torchscript"``
    :raises UsageError: an extension of neither format, or of the other one
    """
    suffix = pathlib.Path(out).suffix.lower()
    by_suffix = next((name for name, suffixes in FORMAT_SUFFIXES.items() if suffix in suffixes), None)
    if by_suffix is None or (fmt is not None and by_suffix != fmt):
        expected = FORMAT_SUFFIXES[fmt] if fmt else [s for suffixes in FORMAT_SUFFIXES.values() for s in suffixes]
        raise UsageError(
            f"{out}: the output must end in {' or '.join(expected)}"
            + (f" for --format {fmt}" if fmt else " (.onnx: ONNX, .pt/.pth: TorchScript)")
        )
    return fmt or by_suffix  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="sb3-pola export", description=export.__doc__)
    parser.add_argument("model", help="a saved POLA model (.zip)")
    parser.add_argument("out", help="output file: .onnx (ONNX) or .pt/.pth (TorchScript)")
    parser.add_argument(
        "--format", choices=export.EXPORT_FORMATS, default=None, help="default: from OUT's extension, which must match it"
    )
    args = parser.parse_args(argv)
    fmt = output_format(args.out, args.format)  # checked before the model is read: nothing is written on a refusal
    model = POLA.load(args.model, device="cpu")
    out = model.export_policy(args.out, format=fmt)
    policy = model.policy
    print(
        f"wrote {out} ({fmt}): {export.INPUT_NAME} [batch, {policy.observation_space.shape[0]}] float32 -> "  # type: ignore[index]
        f"{export.OUTPUT_NAME} [batch, {policy.action_space.shape[0]}], {policy.predict_actor} actor, "  # type: ignore[index]
        f"{policy.n_diffusion_steps} denoising steps"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
