"""Stereo geometry: matching blobs between the eyes and triangulating them in the rig frame."""
