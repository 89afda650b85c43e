"""Physical effects a nominal cloth model may lack, as plugins (entry-point group ``softsbi``)."""
