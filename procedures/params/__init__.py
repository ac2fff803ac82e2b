"""Each built-in procedure's declaration (``NAME``, ``DESCRIPTION``, ``Parameters``) in a module of the
procedure's name, importing no numpy or pandas: ``rig list`` reads these, not the procedures' machinery.
The procedure module imports its declaration from here; a procedure without one is listed from its own
module (the same table, at the cost of its imports)."""
