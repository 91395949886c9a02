"""``python -m airimu.cli``, as torchrun -m launches it."""

from airimu.cli import main

main()
