"""BabyAI as a gpl-dist domain: minigrid's BabyAI levels, its bot as the DAgger expert, corrections
in BabyAI's own words. The domain is ``gpl_babyai.domain.DOMAIN`` (entry point ``babyai``)."""

__version__ = "0.1.0"
