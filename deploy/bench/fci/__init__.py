"""``iem bench fci``: the plug-in against franky-sim's FR3 over the libfranka protocol
(:mod:`.command`), the pick-and-place it runs (:mod:`.schedule`), the two FCI clients in
processes of their own, a franky-control program with the plug-in inside and the service as
``iem run`` runs it (:mod:`.clients`), the scores (:mod:`.score`) and the figures
(:mod:`.figures`).
"""
