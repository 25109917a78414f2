"""Whether training made the model worse: a warning from a run's logged history (``train_history.csv``'s rows), as
when a learning rate is far too high. Stage 1 and stage 2 print it after training and record it in metrics.json."""
from __future__ import annotations

import math

__all__ = ["loss_trend_warning"]


def loss_trend_warning(history: list[dict], desc: str) -> str | None:
    """A warning when training made the loss worse, as when a learning rate is far too high; None otherwise.

    Compared are the means over the log intervals (``loss_mean``), their median over the last fifth (at least
    three), not single batches: batches differ in kind (stage 2's reference views carry a 20x weight against a
    pseudo-colour view's, TCM acts on some views only; a NeRF-synthetic chair's stage 2 logged 0.007 to 0.070 while
    its interval means fell from 0.044 to 0.031). Worse is a tail above the first interval's mean (worse while
    training), or above twice step 1's loss (worse than at the start; step 1 is one batch, hence the margin: a rate
    that wrecks the model at once, 0.15 -> 0.50, is caught; an easy first view, 0.024 -> 0.031, is not).
    Histories without ``loss_mean`` (older checkpoints) compare step 1's loss with the median of the late ones."""
    if not history or not all("loss_mean" in h for h in history):
        return _single_batch_trend(history, desc)
    logged = [h for h in history if math.isfinite(h["loss_mean"]) and math.isfinite(h["loss"])]
    if len(logged) < 5:
        return None
    start, first = logged[0], logged[1]
    tail = sorted(h["loss_mean"] for h in logged[2:][-max(3, len(logged) // 5):])
    last = tail[len(tail) // 2]
    if last > first["loss_mean"]:
        was = f"{first['loss_mean']:.4g} (the mean to step {first['step']})"
    elif last > 2 * start["loss"]:
        was = f"{start['loss']:.4g} at step {start['step']} (more than twice)"
    else:
        return None
    return (f"{desc}: the mean training loss rose from {was} to {last:.4g} (the median of the last {len(tail)} "
            "logged intervals); the model got worse while training (a learning rate too high? see train.optim)")


def _single_batch_trend(history: list[dict], desc: str) -> str | None:
    """:func:`loss_trend_warning` on a history of one-batch losses (``loss`` only)."""
    logged = [(h["step"], h["loss"]) for h in history if math.isfinite(h.get("loss", math.nan))]
    if len(logged) < 4:
        return None
    tail = sorted(v for _, v in logged[1:][-max(3, len(logged) // 5):])
    first, last = logged[0][1], tail[len(tail) // 2]
    if last <= first:
        return None
    return (f"{desc}: the training loss rose from {first:.4g} at step {logged[0][0]} to {last:.4g} (the median of "
            f"the last {len(tail)} logged steps); the model got worse while training (a learning rate too high? see "
            "train.optim)")
