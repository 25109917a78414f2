"""``arcsem``: the Hydra application (``pkg://arcsem.conf``); the work is :func:`arcsem.app.run`.

Examples::

    arcsem experiment=demo
    arcsem dataset=transforms dataset.path=/data/pollen backbone=gs3d stage=check
    arcsem -m backbone=gs2d,gs3d hydra/launcher=joblib
"""
from __future__ import annotations

import hydra
from omegaconf import DictConfig

from .errors import with_error_handling

__all__ = ["hydra_main", "main"]


@hydra.main(config_path="pkg://arcsem.conf", config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> float | None:
    from ..app import run

    metrics = run(cfg)
    value = metrics.get("psnr") if isinstance(metrics, dict) else None  # sweepers may optimise it
    return float(value) if isinstance(value, (int, float)) else None


main = with_error_handling(hydra_main)


if __name__ == "__main__":
    main()
