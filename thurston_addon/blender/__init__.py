"""The Blender layer: translates between Blender and the bpy-free library (settings, render engine,
scene export, the domain guide, batch rendering, results), with the add-on's operators/ and panels/."""
