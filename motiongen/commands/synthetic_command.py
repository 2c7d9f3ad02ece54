"""motiongen synthetic out=DIR [size=default|small] [seed=0] [overwrite=false] [workers=N]"""

from __future__ import annotations

import time

from motiongen.checks import require_output_path
from motiongen.cli import parse_key_values, tool_main
from motiongen.data.format import MotionDataset
from motiongen.synthetic import generate

SPEC = {"out": (str, None), "size": (str, "default"), "seed": (int, 0), "overwrite": (bool, False),
        "workers": (int, None)}
USAGE = "motiongen synthetic out=DIR [size=default|small] [seed=0] [overwrite=true] [workers=N]"


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("out",), usage=USAGE,
                            doc="Generate the embedded synthetic human-scene dataset into out=DIR.")
    require_output_path("out", opts["out"], directory=True)
    t0 = time.perf_counter()
    root = generate(opts["out"], size=opts["size"], seed=opts["seed"], overwrite=opts["overwrite"],
                    workers=opts["workers"])
    ds = MotionDataset.open(root, check_values=False)
    minutes = ds.num_frames / ds.fps / 60
    print(f"synthetic dataset at {root}: {len(ds.scenes)} scenes, {len(ds.sequences)} sequences, "
          f"{ds.num_frames} frames ({minutes:.1f} min at {ds.fps:g} fps), generated in {time.perf_counter() - t0:.1f} s")


main = tool_main(run)


if __name__ == "__main__":
    main()
