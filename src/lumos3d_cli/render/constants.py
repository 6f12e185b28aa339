"""The rasterizer's pinned constants (gsplat's current values unless noted; docs/rendering.md)."""

TILE_SIZE = 16
MAX_ALPHA = 0.99  # alpha = min(MAX_ALPHA, o * exp(-sigma)); gradients stop where it clamps
ALPHA_THRESHOLD = 1.0 / 255.0  # a Gaussian with alpha below this does not touch the pixel
TRANSMITTANCE_THRESHOLD = 1e-4  # a pixel is done when the next transmittance would be <= this
EPS2D = 0.3  # added to the diagonal of every projected 2D covariance (about a third of a pixel)
NEAR_PLANE = 0.01
FAR_PLANE = 1e10
GAUSSIAN_EXTEND = 3.33  # largest radius in standard deviations
MAX_RADIUS = 2.0**30  # (lumos3d's) a stored pixel radius is capped here: int32 radii (a std of 1e8 px overflowed)
MIN_COMPENSATION = 0.005  # floor of the antialiasing opacity compensation
FOV_MARGIN = 0.3  # the EWA Jacobian is evaluated at most this fraction of tan(fov) outside the image
MAX_IMAGE_SIDE = 16384  # (lumos3d's) a larger frame's buffers alone take gigabytes; 100000 px a side was a MemoryError

# Real SH basis constants for degrees 1-4 (3DGS order); SH_C0 and MAX_SH_DEGREE, which the
# files and colour conversions share, live in io/gaussians.py.
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
    -0.4570457994644658, 1.445305721320277, -0.5900435899266435,
)
SH_C4 = (
    2.5033429417967046, -1.7701307697799304, 0.9461746957575601, -0.6690465435572892, 0.10578554691520431,
    -0.6690465435572892, 0.47308734787878004, -1.7701307697799304, 0.6258357354491761,
)
