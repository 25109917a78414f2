"""3DGS with Mip-Splatting's 3-D smoothing filter (Yu et al., CVPR 2024) as an arcsem backbone plugin."""
__all__: list[str] = []
