"""Driving a head: views and turntables, ARKit animation, hair swaps, random heads, and
baking its appearance for mesh export. Everything here renders through
:class:`head360cli.model.head_render.HeadRenderer`."""
