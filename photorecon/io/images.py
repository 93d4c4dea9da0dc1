"""Image and depth-map files: reading with clear errors, writing atomically, colour-mapped previews."""
from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputDataError
from .atomic import atomic_path
from .paths import inside


@functools.cache
def register_heif() -> bool:
    """Let Pillow open HEIC/HEIF photos (``pillow-heif``; its opener applies the photo's rotation and resets
    the EXIF orientation to 1), once per process. False when the package is missing."""
    try:
        import pillow_heif
    except ImportError:
        return False
    pillow_heif.register_heif_opener()
    return True


def open_photo(path: str | Path):
    """``PIL.Image.open`` for a photo of any format photorecon reads (HEIC included: ``register_heif``). Raises
    what ``Image.open`` raises."""
    from PIL import Image

    register_heif()
    return Image.open(path)


def read_bgr(path: str | Path) -> np.ndarray | None:
    """8-bit BGR (H, W, 3) with the EXIF orientation applied, by OpenCV, or by Pillow for what OpenCV cannot
    decode (HEIC; a TIFF whose orientation turns it on its side, 5-8, which OpenCV 5 refuses); None when
    neither can."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is not None:
        return img
    from PIL import ImageOps

    try:
        with open_photo(path) as im:
            return np.ascontiguousarray(np.asarray(ImageOps.exif_transpose(im).convert("RGB"))[..., ::-1])
    except Exception:  # damaged or not an image: the caller's error names the file
        return None


def read_image(path: str | Path) -> np.ndarray:
    """8-bit RGB (H, W, 3); grey images are repeated into three channels. An alpha channel (RGBA, grey +
    alpha) is dropped and the colour kept as stored, not blended with any background: read it as a mask
    with ``read_alpha``. Raises ``InputDataError`` naming the file if it cannot be decoded."""
    path = Path(path)
    img = read_bgr(path)
    if img is None:
        raise InputDataError(f"{path}: cannot read image (missing, corrupt or not an image)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def damaged_image(path: str | Path) -> str | None:
    """Why the image file ``path`` is incomplete (e.g. "truncated: the file ends before the image data does"),
    or None when it decodes to the end. A full decode with Pillow that reports truncation (OpenCV decodes a
    truncated JPEG without an error, grey from where the data stops); JPEGs are decoded at 1/8 scale, which
    still reads every byte of their data. Formats Pillow cannot open are not judged here (None)."""
    from PIL import ImageFile

    path = Path(path)
    try:
        im = open_photo(path)
    except Exception:  # not a format Pillow reads (or not an image): the caller's decoder decides
        return None
    keep = ImageFile.LOAD_TRUNCATED_IMAGES
    ImageFile.LOAD_TRUNCATED_IMAGES = False
    try:
        with im:
            if im.format == "JPEG":
                im.draft(im.mode, (max(1, im.width // 8), max(1, im.height // 8)))
            im.load()
    except (OSError, SyntaxError, ValueError) as exc:
        text = str(exc)
        if "truncated" in text or "broken" in text or "end of" in text.lower():
            return "truncated: the file ends before the image data does (an incomplete copy or download?)"
        return f"damaged: {text}"
    except Exception:  # Pillow's own limits (e.g. decompression-bomb size): not a damaged file
        return None
    finally:
        ImageFile.LOAD_TRUNCATED_IMAGES = keep
    return None


def _png_has_alpha(path: Path) -> bool | None:
    """From a PNG's chunk headers, without decoding pixels: whether it has an alpha channel (colour type 4,
    grey + alpha, or 6, RGBA) or a transparency chunk (tRNS). None when the file is not a PNG."""
    with open(path, "rb") as f:
        if f.read(8) != b"\x89PNG\r\n\x1a\n":
            return None
        while True:
            head = f.read(8)
            if len(head) < 8:
                return False
            length, kind = int.from_bytes(head[:4], "big"), head[4:]
            if kind == b"IHDR":
                data = f.read(length)
                if len(data) >= 10 and data[9] in (4, 6):
                    return True
                f.seek(4, 1)
                continue
            if kind == b"tRNS":
                return True
            if kind in (b"IDAT", b"IEND"):
                return False
            f.seek(length + 4, 1)  # data + CRC


def read_alpha(path: str | Path) -> np.ndarray | None:
    """The alpha channel (H, W) of an RGBA or grey + alpha image (uint8, or uint16 for 16-bit files), or
    None when the image has none. PNG headers are checked first, so an image without alpha is not decoded;
    JPEG never has alpha. Raises ``InputDataError`` naming the file if it cannot be decoded."""
    path = Path(path)
    if path.suffix.lower() in (".jpg", ".jpeg"):
        return None
    try:
        has = _png_has_alpha(path)
    except OSError as exc:
        raise InputDataError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    if has is False:
        return None
    # OpenCV reads the channels as stored, without the EXIF orientation: an oriented photo's alpha through Pillow
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if exif_orientation(path) in (0, 1) else None
    if img is None:
        from PIL import ImageOps

        try:
            with open_photo(path) as im:
                if "A" not in im.getbands():
                    return None
                return np.ascontiguousarray(np.asarray(ImageOps.exif_transpose(im).getchannel("A")))
        except Exception:  # damaged: named below
            pass
    if img is None:
        raise InputDataError(f"{path}: cannot read image (missing, corrupt or not an image)")
    if img.ndim == 3 and img.shape[2] in (2, 4):
        return np.ascontiguousarray(img[:, :, -1])
    return None


MASK_HELP = "masks are NAME.png or NAME.EXT.png (COLMAP's naming, e.g. IMG_1.jpg.png), 0 = ignore the pixel"


def mask_file(folder: str | Path, image_name: str) -> Path | None:
    """The mask of image ``image_name`` in ``folder``: ``NAME.EXT.png`` (COLMAP's naming, checked first) or
    ``NAME.png`` (the image's stem), or None when neither exists. A mask that is a link to a file outside
    ``folder`` raises ``InputDataError`` (``paths.inside``)."""
    folder, name = Path(folder), Path(image_name).name
    for cand in (f"{name}.png", f"{Path(name).stem}.png"):
        if (folder / cand).is_file():
            return inside(folder, cand, f"image {name}")
    return None


def exif_orientation(path: str | Path) -> int:
    """The EXIF orientation (1-8) of an image file, from its header; 1 when it has none or it cannot be read.
    A HEIC photo's is 1: its decoder applies it (``register_heif``)."""
    try:
        with open_photo(path) as im:
            return int(im.getexif().get(0x0112, 1) or 1)
    except Exception:  # not a format PIL reads, or unparsable EXIF: as stored
        return 1


def read_unchanged(path: str | Path) -> np.ndarray | None:
    """The pixels of an image file at their stored depth and channels (OpenCV's order: BGR, BGRA, grey, grey +
    alpha), turned upright by the EXIF orientation: OpenCV's ``IMREAD_UNCHANGED`` where there is none (it
    ignores EXIF, but turns a TIFF by its own orientation tag), else Pillow's ``exif_transpose``. None when
    neither can decode it."""
    if exif_orientation(path) in (0, 1):
        return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    from PIL import ImageOps

    try:
        with open_photo(path) as im:
            im = ImageOps.exif_transpose(im)
            if im.mode not in ("L", "LA", "I;16", "RGB", "RGBA"):
                im = im.convert("RGBA" if "A" in im.getbands() else "RGB")
            a = np.asarray(im)
    except Exception:  # damaged or not an image: the caller names the file
        return None
    if a.ndim == 3 and a.shape[2] >= 3:
        a = a[..., [2, 1, 0, 3][: a.shape[2]]]
    return np.ascontiguousarray(a)


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file as ``read_image`` returns it (EXIF orientation applied), from its
    header where the format allows (PIL), without decoding pixels."""
    path = Path(path)
    try:
        from PIL import Image

        with Image.open(path) as im:
            w, h = im.size
            try:
                orientation = int(im.getexif().get(0x0112, 1) or 1)
            except Exception:  # unparsable EXIF: as stored
                orientation = 1
        return (h, w) if orientation in (5, 6, 7, 8) else (w, h)
    except Exception:  # not a format PIL reads: decode it
        img = read_image(path)
        return img.shape[1], img.shape[0]


def read_mask(path: str | Path, size: tuple[int, int] | None = None, what: str = "") -> np.ndarray:
    """A mask image as boolean (H, W), True where the pixel is used (value > 0; colour masks: any channel).
    ``size``: the (width, height) the mask must have (its image's). Raises ``InputDataError`` naming the
    file when it cannot be read or has another size; ``what`` names its image in that message."""
    path = Path(path)
    m = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if m is None:
        raise InputDataError(f"{path}: cannot read the mask (missing, corrupt or not an image); {MASK_HELP}")
    if m.ndim == 3:
        m = m[:, :, :3].max(axis=2) if m.shape[2] >= 3 else m[:, :, 0]
    if size is not None and (m.shape[1], m.shape[0]) != tuple(size):
        raise InputDataError(f"{path}: mask is {m.shape[1]}x{m.shape[0]} but {what or 'its image'} is "
                             f"{size[0]}x{size[1]}; give masks at the size of their images")
    return m > 0


def match_masks(folder: str | Path, images: dict[str, tuple[int, int] | None]) -> dict[str, Path]:
    """Check a user's mask folder against ``images`` (file name -> (width, height), or None to skip the size
    check) before anything is written: ``{image name: mask file}`` for the images that have a mask.

    Raises ``InputDataError`` naming the folder when it is missing or no mask matches an image name, and
    naming the mask when it has another size than its image (read from the headers, no pixels decoded)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputDataError(f"{folder}: no such mask folder ({MASK_HELP})")
    found = {name: p for name in images if (p := mask_file(folder, name)) is not None}
    if not found:
        n = next(iter(images), "IMG_1.jpg")
        raise InputDataError(f"{folder}: no mask is named after an image (for {n}: {n}.png or {Path(n).stem}.png); "
                             f"{MASK_HELP}")
    for name, p in found.items():
        want = images[name]
        if want is None:
            continue
        got = image_size(p)
        if got != tuple(want):
            raise InputDataError(f"{p}: mask is {got[0]}x{got[1]} but image {name} is {want[0]}x{want[1]}; "
                                 "give masks at the size of their images")
    return found


def write_image(path: str | Path, img: np.ndarray) -> Path:
    """Write an RGB (H, W, 3) or grey (H, W) uint8 image atomically (format from the suffix)."""
    path = Path(path)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            image_write_failed(path, img.nbytes)
    return path


def image_write_failed(path: Path, nbytes: int) -> None:
    """A writer that only says it failed (OpenCV): ``OutputError``, "no space left" when the disk is nearly
    full."""
    from ..errors import OutputError
    from .space import free_bytes, no_space_error

    free = free_bytes(path.parent)
    if free is not None and free < max(nbytes, 1 << 20):
        raise no_space_error(path)
    raise OutputError(f"{path}: could not write the image; check the folder's permissions and space")


def depth_preview(depth: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """Colour-mapped (turbo) RGB preview of a depth map: near = warm, far = cold, no surface = black."""
    d = np.asarray(depth, np.float64)
    valid = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if not valid.any():
        return out
    lo = np.percentile(d[valid], 1) if lo is None else lo
    hi = np.percentile(d[valid], 99) if hi is None else hi
    x = np.clip((d - lo) / max(hi - lo, 1e-12), 0, 1)
    x = ((1 - x) * 255).astype(np.uint8)
    col = cv2.cvtColor(cv2.applyColorMap(x, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    out[valid] = col[valid]
    return out


def write_depth(folder: str | Path, name: str, depth: np.ndarray, confidence: np.ndarray | None = None) -> Path:
    """The synth layout's depth files for one view, each written atomically: ``NAME.npy`` (float32 z-depth),
    ``NAME.conf.npy`` (float32 confidence, when given) and ``NAME.png`` (colour-mapped preview)."""
    folder = Path(folder)
    path = folder / f"{name}.npy"
    with atomic_path(path) as tmp:
        np.save(tmp, np.asarray(depth, np.float32))
    if confidence is not None:
        with atomic_path(folder / f"{name}.conf.npy") as tmp:
            np.save(tmp, np.asarray(confidence, np.float32))
    write_image(folder / f"{name}.png", depth_preview(depth))
    return path


def read_depth(path: str | Path, shape: tuple[int, int] | None = None, view: str | None = None) -> np.ndarray:
    """float32 z-depth (H, W) from a .npy file; NaN/inf/negative values raise, naming the view."""
    path = Path(path)
    name = view or path.stem
    try:
        d = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputDataError(f"view {name}: depth map {path} is missing") from None
    except (ValueError, OSError) as exc:
        raise InputDataError(f"view {name}: {path} is not a readable .npy depth map ({exc})") from None
    if d.ndim != 2:
        raise InputDataError(f"view {name}: depth map {path} has shape {d.shape}, expected (H, W)")
    if shape is not None and d.shape != tuple(shape):
        raise InputDataError(f"view {name}: depth map {path} has shape {d.shape}, but the camera is "
                             f"{shape[1]}x{shape[0]} (expected (H, W) = {tuple(shape)})")
    d = d.astype(np.float32)
    bad = ~np.isfinite(d)
    neg = d < 0
    if bad.any() or neg.any():
        raise InputDataError(f"view {name}: depth map {path} has {int(bad.sum())} NaN/inf and {int(neg.sum())} "
                             "negative values; use 0 for pixels without depth")
    return d


def sample_bilinear(image: np.ndarray, pixels: np.ndarray, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Bilinear samples (N, C) float32 of ``image`` (H, W[, C]) at ``pixels`` (N, 2) = (u, v) in OpenCV's pixel
    convention (centre of the top-left pixel at (0, 0)). Any N (``cv2.remap`` takes maps < 32767 long)."""
    p = np.asarray(pixels, np.float32).reshape(-1, 2)
    n = len(p)
    cols = 4096
    rows = max(1, -(-n // cols))
    pad = np.zeros((rows * cols, 2), np.float32)
    pad[:n] = p
    out = cv2.remap(image, pad[:, 0].reshape(rows, cols), pad[:, 1].reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=border)
    return out.reshape(rows * cols, -1)[:n].astype(np.float32)
