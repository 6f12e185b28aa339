"""What `lumos3d degrade` writes and where: its output set, checked before any image is read.
Needs neither torch nor an image reader, so that a refused command line ends at once."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES
from lumos3d_cli.io.output_paths import check_output_path
from lumos3d_cli.io.output_set import OutputSet

SINGLE_FILE_SUFFIXES = (".png", ".jpg", ".jpeg")  # what io.image_write encodes
BIT_DEPTHS = (8, 16)


def degrade_outputs(inputs: list[Path], output: Path, bit_depth: int, given: Sequence[Path] = ()) -> OutputSet:
    """The outputs of degrading the image files `inputs` into `output` (a folder, or one .png/.jpg
    file for one input), validated before any image is read and kept clear of the inputs and the
    folders `given` for them. Messages name the user's path (the files are written under
    temporary names)."""
    if bit_depth not in BIT_DEPTHS:
        raise InputError(f"{bit_depth}: use 8 or 16", parameter="bit_depth")
    suffix = output.suffix.lower()
    if suffix in IMAGE_SUFFIXES:  # a file name (an .exr or a RAW one too: refused below), not a folder
        if len(inputs) != 1:
            raise InputError(f"{output}: names one file but there are {len(inputs)} inputs; give a folder", parameter="output")
        if suffix not in SINGLE_FILE_SUFFIXES:
            raise InputError(f"{output}: cannot write '{output.suffix}' files; use .png or .jpg", parameter="output")
        if bit_depth != 8 and suffix != ".png":
            raise InputError(f"{output}: JPEG holds 8 bits only; use .png for 16-bit output", parameter="output")
        check_output_path(output, "output")
        # the input as named and, through a link, the file it reaches: its folder is where a twin would sit
        twin = next((path for given_path in inputs for path in (given_path, given_path.resolve())
                     if path.parent.resolve() == output.parent.resolve()
                     and path.stem.casefold() == output.stem.casefold() and path.resolve() != output.resolve()), None)
        if twin is not None:  # 1.jpg and 1.png: a folder no command reads again ("two photos named '1'")
            raise InputError(f"{output}: would sit beside {twin.name} under the same name, and the folder would hold two "
                             "photos of one view; name the output otherwise or write it to another folder",
                             parameter="output")
        return OutputSet(output.parent, "degrade", f"degrade {output.name}", [*inputs, *given]).add_file(output.name)
    check_output_path(output, "output", folder=True)
    # photos given one by one: degraded PNGs beside them in their own folder (1.JPG and 1.png)
    # would make it a folder no command reads again ("two photos named '1'"); a folder inside it is fine
    for folder in sorted({path.parent.resolve() for path in inputs}):
        if output.resolve() == folder:
            raise InputError(f"{output}: is the input folder {folder}; write the outputs to another folder",
                             parameter="output")
    outputs = OutputSet(output, "degrade", "degrade", [*inputs, *given])
    for name in [*(f"{path.stem}.png" for path in inputs), "degradation.json"]:
        outputs.add_file(name)
    return outputs


def is_single_file(output: Path) -> bool:
    """Whether `output` names one image file rather than a folder."""
    return output.suffix.lower() in IMAGE_SUFFIXES
