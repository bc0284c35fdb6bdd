from rest_framework.routers import DefaultRouter

from missions.api.views import VirtualVehicleViewSet

router = DefaultRouter()
router.register("vvs", VirtualVehicleViewSet, basename="vv")

urlpatterns = router.urls
