"""``softsbi train-extractor``: train a keypoint extractor for the image observers."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_JSON, H_SEED, IMAGE_SIZE_OK, SEED_OK, checked, parse_kv
from softsbi.cli.output import Output
from softsbi.core import defaults as D


def train_extractor(kind: str = typer.Argument(..., help="extractor plugin: heatmap (supervised) or transporter "
                                                         "(unsupervised)"),
                    out: Path = typer.Option(..., help="checkpoint to write (.pt)"),
                    data: Optional[Path] = typer.Option(None, help="annotated folder (images/NNNNN.jpg|png + "
                                                                   "keypoints/NNNNN.npy), e.g. "
                                                                   "../shared/data/wiping_keypoints"),
                    simulate: Optional[str] = typer.Option(None, help="instead of --data: render this scenario at "
                                                                      "prior samples (labels = projected cloth "
                                                                      "corners; robot masks from the segmentation)"),
                    backend: str = typer.Option(D.BACKEND, help="with --simulate: simulator plugin"),
                    rollouts: int = typer.Option(D.IMAGE_ROLLOUTS, help="with --simulate: rendered rollouts",
                                                 callback=checked(D.IMAGE_ROLLOUTS_BOUND)),
                    image_size: int = typer.Option(D.IMAGE_SIZE, help="with --simulate: square camera size (px)",
                                                   callback=IMAGE_SIZE_OK),
                    mask_robot: bool = typer.Option(True, help="transporter: leave the robot out of the "
                                                               "reconstruction loss"),
                    opt: list[str] = typer.Option(None, "--opt", help="extractor option name=value (repeatable)"),
                    seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
                    as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Train a keypoint extractor on annotated images or on rendered rollouts; report its test error."""
    from softsbi.workflows.extractor import ExtractorProgress, train_extractor as train  # start-up: numpy, keypoints

    class Bars(ExtractorProgress):
        def __init__(self, p: Any):
            self.p = p

        def message(self, text: str) -> None:
            o.line(text)

        def task(self, description: str, total: int | None):
            t = self.p.add_task(description, total=total)

            def update(done: int, total: int | None = None, loss: float | None = None) -> None:
                label = description if loss is None else f"{description} (loss {loss:.4g})"
                self.p.update(t, completed=done, total=total, description=label)
            return update

    o = Output(as_json)
    with o.progress() as p:
        summary = train(kind, out, data=data, simulate=simulate, backend=backend, rollouts=rollouts,
                        image_size=image_size, mask_robot=mask_robot, options=parse_kv(opt, "--opt"), seed=seed,
                        progress=Bars(p))
    if json_done(o, summary):
        return
    tr = summary["train"]
    o.line(f"trained {kind}: {tr['epochs']} epochs, {tr['seconds']:.0f} s -> {out} "
           f"(summary {out.with_suffix('.json')})")
