"""The add-on's operators: renders into images (view, preview, panorama), the domain guide and the
camera, and the settings presets."""

from . import guide, presets, views

CLASSES = (*views.CLASSES, *guide.CLASSES, *presets.CLASSES)
