"""The Lumos3D network: VGGT-style backbone, camera/depth/Gaussian heads and voxel fusion."""
