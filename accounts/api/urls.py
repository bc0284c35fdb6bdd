"""Routes of the customer endpoints."""

from rest_framework.routers import SimpleRouter

from accounts.api.views import CustomerViewSet

router = SimpleRouter()
router.register("customers", CustomerViewSet, basename="customer")

urlpatterns = router.urls
