"""The viewer's defaults, which the command line's options show: here so that `--help` need not
import viser and torch (viewer.server and viewer.splats, which use them, import those)."""

DEFAULT_HOST = "127.0.0.1"  # this machine only; --host 0.0.0.0 shares the viewer on the network
DEFAULT_PORT = 8080
# The browser holds 32 bytes per splat on the GPU and sorts all of them by depth on the CPU
# (a WebAssembly worker) whenever the view turns: a million splats is 32 MB of scene data and
# keeps the sort well under a second on a laptop, about the size of a 3DGS capture.
DEFAULT_MAX_SPLATS = 1_000_000
