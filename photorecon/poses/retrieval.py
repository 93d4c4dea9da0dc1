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
import tempfile
from pathlib import Path

import numpy as np

log = logging.getLogger("photorecon")

# descriptors sampled from the features database to train the visual words: at most this many in all ...
INDEX_SAMPLE = 100_000
# ... and this many per photo (SIFT's strongest come first in COLMAP's database; a random sample is taken)
INDEX_SAMPLE_PER_IMAGE = 500
# a pair verified with at least this many inliers counts as strong for transitive pairs
STRONG_INLIERS = 100
# a photo with fewer verified pairs than this gets a second retrieval round
WEAK_PAIRS = 3


def _pycolmap():
    from .sfm import _pycolmap as load

    return load()


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
    fewer of each). The photos themselves are indexed when pairs are drawn (``retrieval_pairs``)."""
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
    opt.num_threads = threads
    index.build(opt, pycolmap.FeatureDescriptorsFloat(pycolmap.FeatureExtractorType.SIFT, sample))
    index.write(str(path))
    log.debug("retrieval: %d visual words from %d descriptors of %d photos", words, len(sample), len(ids))
    return path


def retrieval_pairs(database: Path, index: Path, k: int, threads: int = -1,
                    query_ids: list[int] | None = None) -> set[tuple[int, int]]:
    """Each photo (of ``query_ids``, default all) with its ``k`` most similar others by the visual ``index``:
    pairs of image ids (smaller first)."""
    pycolmap = _pycolmap()
    opt = pycolmap.VocabTreePairingOptions()
    opt.vocab_tree_path = str(index)
    opt.num_images = k + 1  # a photo retrieves itself first
    opt.num_threads = threads
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
