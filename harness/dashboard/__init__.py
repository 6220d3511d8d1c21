"""The Streamlit dashboard's rooms (``app.py`` is its entry point and page): cached data access (:mod:`.data`),
charts (:mod:`.charts`) and the tabs (:mod:`.results_tabs`, :mod:`.analysis_tabs`, :mod:`.reproduction_tabs`)."""
