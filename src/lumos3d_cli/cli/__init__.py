"""The `lumos3d` command line (Typer + rich). No model math lives here.

OpenMP worker threads (torch's and numba's) spin while they wait by default; on a laptop where
other programs share the cores that spinning made refinement steps 2-4x slower (0.4-0.9 s
instead of 1.5-4 s; no difference on idle cores), so the command line asks them to sleep
instead unless the user chose otherwise. It must be set before torch is first imported.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
