"""Session products: transfer alignment of a recorded session, antenna poses, CSV, reports and plots
(:mod:`.ta`); the in-flight alignment evaluation report (:mod:`.ifa`)."""
