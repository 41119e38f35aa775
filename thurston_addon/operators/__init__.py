"""The add-on's operators: renders into images (view, preview, panorama), the domain guide and the
camera, the settings presets, and Render on Cluster."""

from . import guide, presets, send_to_farm, views

CLASSES = (*views.CLASSES, *guide.CLASSES, *presets.CLASSES, *send_to_farm.CLASSES)
