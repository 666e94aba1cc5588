"""The names the campaign core imports, from the book, the verdict, the choice and the stored history."""

from helicalib.campaign.basis import stored_basis
from helicalib.campaign.book import (COOLDOWN_INVALID_S, COOLDOWN_VALID_S, EPOCHS_AFTER_DRIFT, FIELD_CURSOR,
                                     MAX_VISIT_POINTS, MAX_VISIT_POINTS_AFTER_DRIFT, Book, Earlier, HeliostatBook,
                                     PlanTable, book_points, earlier_points, fit_size, keep_point, located,
                                     thin_visits, visit_cap)
from helicalib.campaign.choice import (MAX_GUEST_TRIES, MAX_SHARE_INCIDENCE_DEG, Gate, choose_next,
                                       choose_next_vectorised, field_gate, model_spreads, shared_targets)
from helicalib.campaign.verdict import (FIT_LOSS, TRACKING_REFRESH_S, fit_record, loo_errors_mrad, model_from_fit,
                                        prediction_error_mrad, refit, tracking_corrections, verdict)
from helicalib.campaign.verdict import point_approaches as _approaches
from helicalib.campaign.verdict import point_arrays as _arrays
from helicalib.store.history import NO_EPOCH, Epochs, stored_epochs

__all__ = ["COOLDOWN_INVALID_S", "COOLDOWN_VALID_S", "EPOCHS_AFTER_DRIFT", "FIELD_CURSOR", "FIT_LOSS",
           "MAX_GUEST_TRIES", "MAX_SHARE_INCIDENCE_DEG", "MAX_VISIT_POINTS", "MAX_VISIT_POINTS_AFTER_DRIFT",
           "NO_EPOCH", "TRACKING_REFRESH_S", "Book", "Earlier", "Epochs", "Gate", "HeliostatBook", "PlanTable",
           "_approaches", "_arrays", "book_points", "choose_next", "choose_next_vectorised", "earlier_points",
           "field_gate", "fit_record", "fit_size", "keep_point", "located", "loo_errors_mrad", "model_from_fit",
           "model_spreads", "prediction_error_mrad", "refit", "shared_targets", "stored_basis", "stored_epochs",
           "thin_visits", "tracking_corrections", "verdict", "visit_cap"]
