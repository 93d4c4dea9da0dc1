"""Readers and writers at the edges: image folders, COLMAP models, transforms.json, depth maps, datasets."""
