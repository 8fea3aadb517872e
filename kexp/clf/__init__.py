from .certificate import CertificateReport, check_certificate, finsler_margin
from .lyapunov import QuadraticLyapunov
from .synthesis import Clf, ClfConfig, ClfError, clf_from_P, load_clf, save_clf, solve_sdp, synthesize_clf

__all__ = ["CertificateReport", "check_certificate", "finsler_margin", "QuadraticLyapunov", "Clf", "ClfConfig",
           "ClfError", "clf_from_P", "load_clf", "save_clf", "solve_sdp", "synthesize_clf"]
