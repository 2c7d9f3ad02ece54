"""Train a motiongen model: `python train.py [experiment=demo|paper] [key=value ...]`.

With no arguments it trains the demo setting (tiny model) on the embedded synthetic dataset,
generating the dataset into the cache on first use. See docs/config.md for every key.
Same as `motiongen train ...`.
"""

if __name__ == "__main__":
    from motiongen.commands import run_script

    run_script("train")
