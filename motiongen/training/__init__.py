"""The training run: loop, checkpoints, EMA, data order, distributed set-up, figures."""
