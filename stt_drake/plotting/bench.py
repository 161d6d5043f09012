"""The figure of `stt-drake bench`: tube-step cost against obstacle count
(:func:`plot_tube_step_scaling`)."""

from __future__ import annotations

from typing import Any

from matplotlib.figure import Figure


def plot_tube_step_scaling(tube: dict[str, Any], counts: tuple[int, ...]) -> Figure:
    """Log-log plot of one tube step's cost (µs, median) against obstacle count: the
    compiled kernel on the typical and worst fields and the scipy loop, 2D and 3D, with a
    line ∝ count. `tube` is :func:`stt_drake.bench.bench_tube_steps`'s result (keys
    ``"<field>/<n>d/<count>"``)."""
    figure = Figure(figsize=(6.4, 4.4))
    axis = figure.subplots()
    styles = {2: "tab:blue", 3: "tab:orange"}
    for dimension, color in styles.items():
        for field, marker in (("typical", "o"), ("worst", "s")):
            kernel = [tube[f"{field}/{dimension}d/{c}"]["kernel_us"]["median"] for c in counts]
            axis.loglog(
                counts, kernel, marker=marker, color=color, label=f"compiled, {dimension}D, {field}"
            )
        baseline = [tube[f"typical/{dimension}d/{c}"]["baseline_us"]["median"] for c in counts]
        axis.loglog(
            counts, baseline, ls="--", marker="x", color=color, label=f"scipy loop, {dimension}D"
        )
    reference = tube[f"typical/2d/{counts[0]}"]["kernel_us"]["median"]
    axis.loglog(
        counts, [reference * c / counts[0] for c in counts], ls=":", color="gray", label="∝ count"
    )
    axis.set_xlabel("obstacles")
    axis.set_ylabel("one tube step (µs, median)")
    axis.set_title("Tube step cost against obstacle count")
    axis.grid(True, which="both", alpha=0.3)
    axis.legend(fontsize=7)
    figure.tight_layout()
    return figure
