"""The Lumos3D network: VGGT-style backbone, camera/depth/Gaussian heads and voxel fusion.

The public API is re-exported (lazily) from the package root:

    import lumos3d_cli
    model = lumos3d_cli.load_model("checkpoints/lumos3d.safetensors")  # or VGGT's model.pt, AnySplat's
    prepared = model.prepare(images)                                   # [V, 3, H, W] in [0, 1], any size
    output = model(prepared.images[None])                              # Lumos3DOutput
"""
