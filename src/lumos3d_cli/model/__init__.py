"""The Lumos3D network: VGGT-style backbone, camera/depth/Gaussian heads, the appearance operator
and voxel fusion. Its public names are exported lazily by the package root (`lumos3d_cli`):

    from lumos3d_cli import load_model
    model = load_model("checkpoints/lumos3d.safetensors")  # or VGGT's model.pt, AnySplat's model.safetensors
    prepared = model.prepare(images)                        # [V, 3, H, W] in [0, 1], any size
    output = model(prepared.images[None])                   # Lumos3DOutput
"""
