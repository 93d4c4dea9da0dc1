"""Image pairs for large unordered photo sets by image retrieval, with no download: a visual index (COLMAP's
``VisualIndex``, a bag of visual words) trained on a sample of the capture's own SIFT descriptors, each photo
matched with the ``k`` photos most like it, then loops closed (``match_retrieval``):

1. retrieval: each photo with its ``k`` most similar photos (COLMAP's vocabulary-tree pairing on the index);
2. transitive pairs: where i-j and j-l verified with many inliers, i-l is tried too (a few per photo,
   strongest first): it ties neighbourhoods the retrieval ranked apart, as on a walk round an object;
3. a second round for photos left with few verified pairs: their next ``k`` retrieval candidates.

Every pair goes through COLMAP's matching and geometric verification (``match_pairs``), as exhaustive matching
does; only the choice of pairs differs.
"""
from __future__ import annotations

import logging
import os
import re
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ._colmap import _pycolmap

log = logging.getLogger("photorecon")

# descriptors sampled from the features database to train the visual words: at most this many in all ...
INDEX_SAMPLE = 100_000
# ... and this many per photo (SIFT's strongest come first in COLMAP's database; a random sample is taken)
INDEX_SAMPLE_PER_IMAGE = 500
# a pair verified with at least this many inliers counts as strong for transitive pairs
STRONG_INLIERS = 100
# a photo with fewer verified pairs than this gets a second retrieval round
WEAK_PAIRS = 3


# FAISS's note when COLMAP trains the coarse search index over the visual words (2 sqrt(W) cells for W words,
# and FAISS asks for 39 points per cell): every index under 6,084 words gets it, whatever the photos. The words
# are all indexed and searched; it is not a failure and nothing to act on, so it shows with --verbose only.
FAISS_NOTE = re.compile(r"^WARNING clustering \d+ points to \d+ centroids: please provide at least \d+ training points")


@contextmanager
def native_stderr_filtered(drop: re.Pattern, what: str = "retrieval"):
    """During the block, the process's stderr (file descriptor 2, where native libraries print) goes to a
    temporary file; afterwards its lines that ``drop`` matches are logged at debug level (``what``: their
    source) and the others written to stderr as they were. Lines other threads wrote meanwhile are kept, only
    later. Without a usable descriptor 2 the block runs as it is."""
    try:
        sys.stderr.flush()
    except (AttributeError, ValueError, OSError):
        pass
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            kept = []
            for line in tmp.read().decode("utf-8", "replace").splitlines(keepends=True):
                if drop.search(line):
                    log.debug("%s: %s", what, line.rstrip())
                else:
                    kept.append(line)
            if kept:
                try:
                    os.write(2, "".join(kept).encode())
                except OSError:  # pragma: no cover
                    pass


def database_images(database: Path) -> dict[int, str]:
    """The images of a COLMAP database: {image id: name}."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        return {im.image_id: im.name for im in db.read_all_images()}
    finally:
        db.close()


def visual_words(num_images: int) -> int:
    """Visual words of the index for ``num_images`` photos: 1024 up to 128 photos, more for larger sets (about
    8 per photo, at most 8192), so that a word still separates places on the object; ``build_index`` takes
    fewer where its sample of descriptors is too small to train them."""
    return int(min(8192, max(1024, 1 << int(np.ceil(np.log2(max(1, num_images) * 8))))))


def build_index(database: Path, path: Path, seed: int = 0, threads: int = -1) -> Path:
    """A visual index of the photos in the COLMAP ``database``, written to ``path``: visual words trained on up
    to ``INDEX_SAMPLE`` descriptors sampled evenly over the photos (a random ``INDEX_SAMPLE_PER_IMAGE`` or
    fewer of each). The photos themselves are indexed when pairs are drawn (``retrieval_pairs``). The same
    database and ``seed`` give the same index, byte for byte (``threads`` is not used for it: see below)."""
    pycolmap = _pycolmap()
    rng = np.random.default_rng(seed)
    db = pycolmap.Database.open(str(database))
    try:
        ids = [im.image_id for im in db.read_all_images()]
        per = max(50, min(INDEX_SAMPLE_PER_IMAGE, INDEX_SAMPLE // max(1, len(ids))))
        parts = []
        for i in ids:
            d = np.asarray(db.read_descriptors(i).data)
            if len(d):
                parts.append(d[rng.choice(len(d), min(len(d), per), replace=False)])
    finally:
        db.close()
    sample = np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, 128), np.float32)
    # k-means (FAISS) wants at least 39 training descriptors per word
    words = min(visual_words(len(ids)), 1 << int(np.log2(max(64, len(sample) // 39))))
    index = pycolmap.VisualIndex.create(128, 64)
    opt = pycolmap.VisualIndex.BuildOptions()
    opt.num_visual_words = words
    # The same photos, the same index (and so the same pairs): COLMAP draws the Hamming embedding's projection
    # from its random generator (seeded here; unseeded it differs every run), and on more than one thread the
    # words' search index and embedding differ from run to run even seeded (16 ring views: 111, 112 or 113 pairs
    # from the same features). The bulk of the work, the k-means of the words, runs on FAISS's own threads
    # whatever this setting: the build took the same CPU time (24k descriptors, 512 words: 16-17 CPU s, 2026-11-28).
    opt.num_threads = 1
    pycolmap.set_random_seed(seed)
    with native_stderr_filtered(FAISS_NOTE, "retrieval: FAISS"):
        index.build(opt, pycolmap.FeatureDescriptorsFloat(pycolmap.FeatureExtractorType.SIFT, sample))
    index.write(str(path))
    log.debug("retrieval: %d visual words from %d descriptors of %d photos", words, len(sample), len(ids))
    return path


def retrieval_pairs(database: Path, index: Path, k: int, threads: int = -1,
                    query_ids: list[int] | None = None) -> set[tuple[int, int]]:
    """Each photo (of ``query_ids``, default all) with its ``k`` most similar others by the visual ``index``:
    pairs of image ids (smaller first); the same every run (``threads`` is not used: see below)."""
    pycolmap = _pycolmap()
    opt = pycolmap.VocabTreePairingOptions()
    opt.vocab_tree_path = str(index)
    opt.num_images = k + 1  # a photo retrieves itself first
    # one thread: on more, the same index gave other pairs now and then (48 ring views, 6 runs: 2 different
    # sets of pairs; on one, 1), at the same CPU time (2.3 s a run, 2026-11-28)
    opt.num_threads = 1
    db = pycolmap.Database.open(str(database))
    try:
        gen = pycolmap.VocabTreePairGenerator(opt, db, list(query_ids or []))
        pairs = gen.all_pairs()
    finally:
        db.close()
    return {(min(a, b), max(a, b)) for a, b in pairs if a != b}


def verified_pairs(database: Path) -> dict[tuple[int, int], int]:
    """The verified pairs of a matched COLMAP database: {(image id, image id): inliers}."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        ids, geoms = db.read_two_view_geometries()
    finally:
        db.close()
    out = {}
    for pid, g in zip(ids, geoms):
        n = len(g.inlier_matches)
        if n:
            out[tuple(sorted(pycolmap.pair_id_to_image_pair(pid)))] = n
    return out


def transitive_pairs(verified: dict[tuple[int, int], int], tried: set[tuple[int, int]], per_image: int,
                     strong: int = STRONG_INLIERS) -> set[tuple[int, int]]:
    """Loop closing: pairs i-l not ``tried`` where i-j and j-l both verified with at least ``strong`` inliers,
    strongest first (by the weaker of the two), at most ``per_image`` new pairs per photo."""
    nbrs: dict[int, list[tuple[int, int]]] = {}
    for (a, b), n in verified.items():
        if n >= strong:
            nbrs.setdefault(a, []).append((b, n))
            nbrs.setdefault(b, []).append((a, n))
    cand: dict[tuple[int, int], int] = {}
    for j, adj in nbrs.items():
        for x, (i, ni) in enumerate(adj):
            for l, nl in adj[x + 1:]:
                p = (min(i, l), max(i, l))
                if p not in tried:
                    cand[p] = max(cand.get(p, 0), min(ni, nl))
    count: dict[int, int] = {}
    out = set()
    for p, _ in sorted(cand.items(), key=lambda kv: (-kv[1], kv[0])):
        if count.get(p[0], 0) < per_image and count.get(p[1], 0) < per_image:
            out.add(p)
            count[p[0]] = count.get(p[0], 0) + 1
            count[p[1]] = count.get(p[1], 0) + 1
    return out


def match_pairs(database: Path, pairs, mopt, vopt=None) -> int:
    """Match and verify (COLMAP's geometric verification, ``vopt``: its options, each pair's RANSAC seeded) the
    image pairs ``pairs`` (names or ids) in ``database``; pairs already matched there are skipped by COLMAP.
    Returns the number of pairs given."""
    pycolmap = _pycolmap()
    pairs = list(pairs)
    if not pairs:
        return 0
    if not isinstance(pairs[0][0], str):
        names = database_images(database)
        pairs = [(names[a], names[b]) for a, b in pairs]
    with tempfile.NamedTemporaryFile("w", suffix=".txt", dir=database.parent, delete=False) as f:
        f.write("".join(f"{a} {b}\n" for a, b in pairs))
    try:
        popt = pycolmap.ImportedPairingOptions()
        popt.match_list_path = f.name
        pycolmap.match_image_pairs(str(database), matching_options=mopt, pairing_options=popt,
                                   verification_options=vopt or pycolmap.TwoViewGeometryOptions(),
                                   device=pycolmap.Device.cpu)
    finally:
        Path(f.name).unlink(missing_ok=True)
    return len(pairs)


def match_retrieval(database: Path, k: int, mopt, seed: int = 0, threads: int = -1, vopt=None) -> dict:
    """Retrieval matching of the photos in the COLMAP ``database`` (features extracted, nothing matched yet;
    see the module docstring). Returns what was done: pairs per round and photos without any verified pair."""
    ids = sorted(database_images(database))
    with tempfile.TemporaryDirectory(dir=database.parent, prefix=".index") as tmp:
        index = build_index(database, Path(tmp) / "index.bin", seed, threads)
        tried = retrieval_pairs(database, index, k, threads)
        match_pairs(database, sorted(tried), mopt, vopt)
        verified = verified_pairs(database)
        loops = transitive_pairs(verified, tried, per_image=max(1, k // 2))
        match_pairs(database, sorted(loops), mopt, vopt)
        tried |= loops
        verified = verified_pairs(database)
        degree = {i: 0 for i in ids}
        for a, b in verified:
            degree[a] += 1
            degree[b] += 1
        weak = [i for i in ids if degree[i] < WEAK_PAIRS]
        second: set[tuple[int, int]] = set()
        if weak:
            second = retrieval_pairs(database, index, 2 * k, threads, query_ids=weak) - tried
            match_pairs(database, sorted(second), mopt, vopt)
            tried |= second
    stats = {"retrieval": len(tried) - len(loops) - len(second), "transitive": len(loops),
             "second_round": len(second), "pairs": len(tried), "weak": len(weak)}
    log.info("retrieval matching: %d pairs of %d photos (k=%d: %d retrieved, %d transitive, %d for %d photos "
             "with few pairs)", len(tried), len(ids), k, stats["retrieval"], len(loops), len(second), len(weak))
    return stats
