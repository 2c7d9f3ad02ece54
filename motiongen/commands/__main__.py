"""`python -m motiongen.commands <command> ...`: the `motiongen` console script."""

from motiongen.commands import main

main()
