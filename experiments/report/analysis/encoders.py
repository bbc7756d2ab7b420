"""Groups whose frames were seen through a pretrained perception encoder (docs/perception.md): the part of a group's
`Key` that keeps two encoders (and a frozen encoder from a fine-tuned one) apart, and how titles, headings and figure
names say which encoder and how it was used."""

from __future__ import annotations

from ape_jax.pipeline import results as results_lib


def perception_of(r: results_lib.Results) -> str | None:
    """`Key.perception` of a file: its encoder's SHA-256 (12 digits), `:readout` or `:finetune`; None: no encoder."""
    recipe = (r.settings or {}).get("recipe") or {}
    sha, output = recipe.get("perception_sha256"), recipe.get("perception_output") or "embedding"
    output = "finetune" if recipe.get("perception_training") == "finetune" else output
    return (sha[:12] + ("" if output == "embedding" else f":{output}")) if sha else None


def encoder_words(perception: str) -> str:
    """How titles name a `Key.perception`: `"through the pretrained encoder 0fe101f2"`, `"..., fine-tuned"`,
    `"...'s readout"`."""
    sha, _, output = perception.partition(":")
    return f"through the pretrained encoder {sha[:8]}" + (", fine-tuned" if output == "finetune" else
                                                          f"'s {output}" if output else "")


def encoder_stem(perception: str) -> str:
    """A `Key.perception`'s part of figure file names: `enc0fe101f2`, `enc0fe101f2-finetune`."""
    sha, _, output = perception.partition(":")
    return f"enc{sha[:8]}" + (f"-{output}" if output else "")
