"""Reading a photo: faces (:mod:`.faces`), the 478-point face mesh and blendshape scores
(:mod:`.mesh478`), the 68 iBUG points from the mesh (:mod:`.ibug68`), hair probability
(:mod:`.hair`), and the third-party model files and their runtime
(:mod:`.runtime`)."""
