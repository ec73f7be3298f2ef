"""In-flight alignment of the main POS against GNSS ([Fang2012]): the large-heading-error model
(:mod:`.model`) and the ADD2 / DD2 / AEKF pipeline (:mod:`.pipeline`)."""
